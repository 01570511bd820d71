//! Sending a recorded take: every frame, in order, from the caller's thread.

use std::net::{SocketAddr, UdpSocket};

use mouthpiece_export::{HeadKeys, TakeFrame};
use mouthpiece_output::{
    visemes_from, CurveNaming, MouthSource, RigCurves, RigVisemes, VisemeNaming,
};
use nalgebra::{Matrix3, UnitQuaternion};

use crate::link::open_socket;
use crate::{axes_rotation, VmcFrame, VmcPacket};

/// Sends VMC frames from the caller's thread, every frame to every target, in order: for
/// playing a take, where each frame is due at its time and none may be dropped (the live
/// output's [`crate::OscOutput`] drops the oldest instead of waiting).
pub struct VmcSender {
    packet: VmcPacket,
    axes: UnitQuaternion<f64>,
    sockets: Vec<(SocketAddr, UdpSocket)>,
    bytes: Vec<u8>,
    /// Datagrams sent, and sends that failed (a target refusing: nothing listens there).
    pub sent: u64,
    pub errors: u64,
}

impl VmcSender {
    /// `axes`: the character's head-frame axes (left, up, forward) in its model frame.
    pub fn new(
        targets: &[SocketAddr],
        axes: &Matrix3<f64>,
        head: bool,
        eyes: bool,
        names: CurveNaming,
        visemes: VisemeNaming,
    ) -> std::io::Result<Self> {
        let sockets = targets
            .iter()
            .map(|&addr| Ok((addr, open_socket(addr)?)))
            .collect::<std::io::Result<_>>()?;
        Ok(VmcSender {
            packet: VmcPacket::new(head, eyes, names, visemes),
            axes: axes_rotation(axes),
            sockets,
            bytes: Vec::with_capacity(2048),
            sent: 0,
            errors: 0,
        })
    }

    /// Sends one frame's bundles to every target. A target that refuses is counted, not an
    /// error: a receiver started later still gets the frames after it.
    pub fn send(&mut self, frame: &VmcFrame) {
        self.packet.fill(frame, &self.axes);
        for i in 0..self.packet.packets().len() {
            self.packet.encode(i, &mut self.bytes);
            for (_, socket) in &self.sockets {
                match socket.send(&self.bytes) {
                    Ok(_) => self.sent += 1,
                    Err(_) => self.errors += 1,
                }
            }
        }
    }
}

/// A take frame as the live output sends it: without a rig (before the neutral pose) every
/// curve and viseme at rest; without a head, identities.
impl From<&TakeFrame> for VmcFrame {
    fn from(frame: &TakeFrame) -> Self {
        let f32s = |q: [f64; 4]| q.map(|v| v as f32);
        let head = frame.head.unwrap_or(HeadKeys::REST);
        VmcFrame {
            t: frame.t,
            curves: frame.rig.map(|r| RigCurves(r.curves.map(|v| v as f32))),
            visemes: frame
                .rig
                .map(|r| RigVisemes(visemes_from(&r.curves).map(|v| v as f32))),
            head: f32s(head.head),
            eye_left: f32s(head.eye_left),
            eye_right: f32s(head.eye_right),
            // A take line does not say what drove it live.
            source: MouthSource::Camera,
        }
    }
}
