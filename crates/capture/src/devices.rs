//! What `mouthpiece devices` lists: OpenNI2 devices with their modes, V4L2 nodes with their
//! formats and sizes.

use std::fmt::{self, Write as _};
use std::path::PathBuf;

/// One OpenNI2 device.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenNiDevice {
    pub uri: String,
    pub vendor: String,
    pub name: String,
    /// `(sensor, modes)`; or why the device could not be opened to ask (busy, …).
    pub modes: Result<Vec<(String, Vec<String>)>, Unavailable>,
}

/// One V4L2 format of a node.
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Format {
    pub fourcc: String,
    pub description: String,
    pub sizes: Vec<(u32, u32)>,
}

/// One V4L2 device node.
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Node {
    pub path: PathBuf,
    pub card: String,
    pub driver: String,
    pub formats: Vec<V4l2Format>,
    /// A depth format (Z16, Y16, …) is offered.
    pub looks_like_depth: bool,
    /// Why the node could not be queried.
    pub error: Option<String>,
}

/// Everything found.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceReport {
    /// The OpenNI2 devices, or why OpenNI2 could not be asked.
    pub openni2: Result<Vec<OpenNiDevice>, Unavailable>,
    pub v4l2: Vec<V4l2Node>,
}

/// Why OpenNI2, or one of its devices, could not be asked (the report is a snapshot, so the
/// cause is kept as its message).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Unavailable {
    #[error("{0}")]
    OpenNi2(String),
    #[error("cannot open it: {0} (in use by another process?)")]
    Open(String),
    #[error("OpenNI2 support is not built in (feature openni2)")]
    NotBuilt,
}

/// FourCCs of depth formats.
pub const DEPTH_FOURCCS: [&str; 5] = ["Z16 ", "Y16 ", "INVZ", "INZI", "Y12I"];

/// Lists OpenNI2 devices (opening each briefly to read its modes) and V4L2 nodes.
pub fn list() -> DeviceReport {
    DeviceReport {
        openni2: list_openni2(),
        v4l2: list_v4l2(),
    }
}

#[cfg(feature = "openni2")]
fn list_openni2() -> Result<Vec<OpenNiDevice>, Unavailable> {
    use openni2::{Device, SensorType};
    let devices = openni2::devices().map_err(|e| Unavailable::OpenNi2(e.to_string()))?;
    Ok(devices
        .into_iter()
        .map(|d| {
            let modes = Device::open(&d.uri)
                .map_err(|e| Unavailable::Open(e.to_string()))
                .map(|dev| {
                    [SensorType::Depth, SensorType::Color, SensorType::Ir]
                        .into_iter()
                        .filter_map(|s| match dev.sensor_modes(s) {
                            Ok(Some(modes)) => {
                                Some((s.to_string(), modes.iter().map(|m| m.to_string()).collect()))
                            }
                            _ => None,
                        })
                        .collect()
                });
            OpenNiDevice {
                uri: d.uri,
                vendor: d.vendor,
                name: d.name,
                modes,
            }
        })
        .collect())
}

#[cfg(not(feature = "openni2"))]
fn list_openni2() -> Result<Vec<OpenNiDevice>, Unavailable> {
    Err(Unavailable::NotBuilt)
}

#[cfg(feature = "v4l2")]
fn list_v4l2() -> Vec<V4l2Node> {
    crate::v4l2::video_nodes()
        .into_iter()
        .map(|p| crate::v4l2::describe_node(&p))
        .collect()
}

#[cfg(not(feature = "v4l2"))]
fn list_v4l2() -> Vec<V4l2Node> {
    Vec::new()
}

impl fmt::Display for DeviceReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "OpenNI2 devices:")?;
        match &self.openni2 {
            Err(e) => writeln!(f, "  (OpenNI2 unavailable: {e})")?,
            Ok(list) if list.is_empty() => writeln!(
                f,
                "  none found (the Dummy test device is always there: openni2:Dummy)"
            )?,
            Ok(list) => {
                for d in list {
                    writeln!(f, "  openni2:{}  {} {}", d.uri, d.vendor, d.name)?;
                    match &d.modes {
                        Err(e) => writeln!(f, "    {e}")?,
                        Ok(sensors) => {
                            for (sensor, modes) in sensors {
                                writeln!(f, "    {sensor}: {}", modes.join(", "))?;
                            }
                        }
                    }
                }
            }
        }
        writeln!(f, "V4L2 nodes:")?;
        if self.v4l2.is_empty() {
            writeln!(f, "  none found (no /dev/video*)")?;
        }
        for n in &self.v4l2 {
            let kind = if n.looks_like_depth {
                "depth"
            } else {
                "colour"
            };
            if let Some(e) = &n.error {
                writeln!(f, "  {}  {e}", n.path.display())?;
                continue;
            }
            writeln!(
                f,
                "  {}  {} ({}), looks like {kind}",
                n.path.display(),
                n.card,
                n.driver
            )?;
            if n.formats.is_empty() {
                writeln!(f, "    no capture formats (a metadata or output node)")?;
            }
            for fmt in &n.formats {
                let mut sizes = String::new();
                for (i, (w, h)) in fmt.sizes.iter().enumerate() {
                    let _ = write!(sizes, "{}{w}x{h}", if i == 0 { "" } else { " " });
                }
                writeln!(
                    f,
                    "    {} ({}): {sizes}",
                    fmt.fourcc.trim_end(),
                    fmt.description
                )?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_report_says_so() {
        let r = DeviceReport {
            openni2: Ok(vec![]),
            v4l2: vec![],
        };
        let text = r.to_string();
        assert!(text.contains("OpenNI2 devices:\n  none found"), "{text}");
        assert!(text.contains("V4L2 nodes:\n  none found"), "{text}");
    }

    #[test]
    fn a_report_lists_modes_and_formats() {
        let r = DeviceReport {
            openni2: Ok(vec![OpenNiDevice {
                uri: "1d27/0601@1/5".into(),
                vendor: "PrimeSense".into(),
                name: "PS1080".into(),
                modes: Ok(vec![(
                    "depth".into(),
                    vec!["640x480 @ 30 fps DEPTH_1_MM".into()],
                )]),
            }]),
            v4l2: vec![V4l2Node {
                path: "/dev/video2".into(),
                card: "Intel(R) RealSense(TM) Depth Camera 435".into(),
                driver: "uvcvideo".into(),
                formats: vec![V4l2Format {
                    fourcc: "Z16 ".into(),
                    description: "16-bit Depth".into(),
                    sizes: vec![(848, 480), (640, 480)],
                }],
                looks_like_depth: true,
                error: None,
            }],
        };
        let text = r.to_string();
        assert!(
            text.contains("openni2:1d27/0601@1/5  PrimeSense PS1080"),
            "{text}"
        );
        assert!(
            text.contains("depth: 640x480 @ 30 fps DEPTH_1_MM"),
            "{text}"
        );
        assert!(
            text.contains(
                "/dev/video2  Intel(R) RealSense(TM) Depth Camera 435 (uvcvideo), looks like depth"
            ),
            "{text}"
        );
        assert!(
            text.contains("Z16 (16-bit Depth): 848x480 640x480"),
            "{text}"
        );
    }
}
