//! `.oni` replay: the file checked and, when it needs it, repaired in a copy; frames in
//! order, paced, seeking by reading forward, looping.

use super::*;

impl OpenNiSource {
    pub(super) fn open_file_impl(
        replay: &ReplaySpec,
        config: &CaptureConfig,
        record_to: Option<&Path>,
    ) -> Result<(OpenNiSource, Option<OniRecording>), SourceError> {
        let spec = crate::SourceSpec::Replay(replay.clone()).to_string();
        let path = &replay.path;
        if !path.is_file() {
            return Err(open_error(
                &spec,
                format!("no such file: {}", path.display()),
            ));
        }
        // Check every record in Rust before OpenNI2 sees the file: its player crashes the
        // process (signal 11) on some inconsistent files instead of failing.
        let records = openni2::oni_check::validate(path, true).map_err(|e| match e {
            oni_file::OniFileError::Io { .. } => {
                open_error_with(&spec, format!("cannot read {}", path.display()), e)
            }
            _ => SourceError::Format {
                spec: spec.clone(),
                message: format!("{} is not a readable .oni file", path.display()),
                cause: Some(Box::new(e)),
            },
        })?;
        let complete = records
            .last()
            .is_some_and(|r| r.kind == oni_file::record_type::END);
        if !records
            .iter()
            .any(|r| r.kind == oni_file::record_type::NEW_DATA)
        {
            return Err(format_error(
                &spec,
                format!("{} holds no frames", path.display()),
            ));
        }
        let nodes: std::collections::HashSet<u32> = records
            .iter()
            .filter(|r| {
                r.kind == oni_file::record_type::NODE_ADDED
                    || r.kind == oni_file::record_type::NODE_ADDED_1_0_0_5
            })
            .map(|r| r.node_id)
            .collect();
        let cropped: std::collections::HashSet<u32> = records
            .iter()
            .filter(|r| r.property.as_deref() == Some("xnCropping"))
            .map(|r| r.node_id)
            .collect();
        let (play_path, fixed_copy) = if !complete || !nodes.is_subset(&cropped) {
            // Cut short (OpenNI2's player refuses such files), or written from streams without
            // cropping (Dummy driver, some third-party drivers: OpenNI2 would play no frames).
            // Play a repaired copy; the user's file is not touched.
            let dir = tempfile::tempdir()
                .map_err(|e| open_error_with(&spec, "cannot create a temporary directory", e))?;
            let copy = dir
                .path()
                .join(path.file_name().unwrap_or_else(|| "replay.oni".as_ref()));
            if complete {
                std::fs::copy(path, &copy).map_err(|e| {
                    open_error_with(&spec, format!("cannot copy {}", path.display()), e)
                })?;
            } else {
                let repair =
                    oni_file::repair_truncated(path, &copy).map_err(|e| SourceError::Format {
                        spec: spec.clone(),
                        message: format!("{} is truncated and cannot be repaired", path.display()),
                        cause: Some(Box::new(e)),
                    })?;
                tracing::warn!(
                    file = %path.display(), frames = ?repair.frames, dropped_bytes = repair.dropped_bytes,
                    "playing a truncated .oni up to its last complete frame"
                );
            }
            oni_file::add_missing_cropping(&copy, |_| DEFAULT_FOV_RAD).map_err(|e| {
                open_error_with(
                    &spec,
                    "cannot add the cropping records OpenNI2's player needs",
                    e,
                )
            })?;
            tracing::info!(file = %path.display(), "file lacks cropping records; playing a fixed copy");
            (copy, Some(dir))
        } else {
            (path.clone(), None)
        };
        let uri = play_path
            .to_str()
            .ok_or_else(|| open_error(&spec, "the path is not UTF-8"))?
            .to_string();
        let (session, negotiated, description, recorder) =
            open_session(&spec, &uri, true, config, record_to)?;
        let recording = recorder.map(|r| OniRecording::new(r, record_to, &negotiated));
        let frames = (
            session
                .depth
                .number_of_frames()
                .ok()
                .flatten()
                .unwrap_or(u32::MAX),
            session
                .color
                .number_of_frames()
                .ok()
                .flatten()
                .unwrap_or(u32::MAX),
        );
        let state = ReplayState {
            spec: replay.clone(),
            play_path,
            _fixed_copy: fixed_copy,
            frames,
            received: (0, 0),
            pacer: replay.speed.map(crate::pace::Pacer::new),
            skip_until_us: (replay.start_s * 1e6) as u64,
            loop_offset_us: 0,
            last_ts_us: 0,
            loops: 0,
            ended: false,
        };
        Ok((
            Self::assemble(
                spec,
                session,
                negotiated,
                description,
                Kind::Replay(Box::new(state)),
                config,
            ),
            recording,
        ))
    }

    /// Replay only: continue from `t` after the start of the recording. Forward seeks read
    /// and drop frames; backward seeks reopen the file and read forward (OpenNI2's seek
    /// command crashes its player, an upstream OpenNI2 bug).
    pub fn seek(&mut self, t: Duration) -> Result<(), SourceError> {
        let target = t.as_micros() as u64;
        let Kind::Replay(state) = &mut self.kind else {
            return Err(open_error(&self.spec, "only replays can seek"));
        };
        let position = state.last_ts_us.saturating_sub(state.loop_offset_us);
        if target < position || state.ended {
            self.restart()?;
        }
        if let Kind::Replay(state) = &mut self.kind {
            state.skip_until_us = target;
            if let Some(p) = &mut state.pacer {
                p.reset();
            }
        }
        Ok(())
    }

    /// Reopens the replay file from its start.
    pub(super) fn restart(&mut self) -> Result<(), SourceError> {
        let Kind::Replay(state) = &mut self.kind else {
            return Ok(());
        };
        // Drop first: the old player must be gone before a new one opens the file.
        self.session = None;
        self.pairer.clear();
        let uri = state.play_path.to_str().unwrap_or_default().to_string();
        let (session, _, _, _) = open_session(&self.spec, &uri, true, &self.config, None)?;
        state.received = (0, 0);
        state.ended = false;
        if let Some(p) = &mut state.pacer {
            p.reset();
        }
        self.session = Some(session);
        Ok(())
    }

    pub(super) fn next_replay(&mut self) -> Result<Option<Frame>, SourceError> {
        loop {
            let Kind::Replay(state) = &mut self.kind else {
                unreachable!("replay only")
            };
            if state.ended {
                return Ok(None);
            }
            if let Some((d, c)) = self.pairer.take_in_order() {
                let Kind::Replay(state) = &mut self.kind else {
                    unreachable!()
                };
                let rec_ts = c.timestamp_us;
                if rec_ts < state.skip_until_us {
                    continue;
                }
                if let Some(pacer) = &mut state.pacer {
                    let wait = pacer.wait(Instant::now(), rec_ts.saturating_mul(1000), &self.spec);
                    if !wait.is_zero() {
                        std::thread::sleep(wait);
                    }
                }
                let ts = rec_ts + state.loop_offset_us;
                state.last_ts_us = ts;
                // Received when handed out (after the pacing sleep), as a camera's frame.
                return self.build_frame(d, c, ts).map(|mut f| {
                    f.host_rx = Instant::now();
                    Some(f)
                });
            }
            let Kind::Replay(state) = &mut self.kind else {
                unreachable!()
            };
            let all_read = state.received.0 >= state.frames.0 && state.received.1 >= state.frames.1;
            let event = if all_read {
                None
            } else {
                let session = self
                    .session
                    .as_ref()
                    .ok_or_else(|| lost_error(&self.spec, "replay closed", None))?;
                session
                    .reader
                    .recv_timeout(FILE_STALL)
                    .map_err(|e| SourceError::Format {
                        spec: self.spec.clone(),
                        message: "the OpenNI2 player stopped".into(),
                        cause: Some(Box::new(e)),
                    })?
            };
            match event {
                Some(ev) => self.accept(ev, false)?,
                None => {
                    let Kind::Replay(state) = &mut self.kind else {
                        unreachable!()
                    };
                    if !all_read {
                        tracing::warn!(
                            spec = %self.spec,
                            depth = state.received.0,
                            color = state.received.1,
                            "the recording ended early (truncated file?): played to its last readable frame"
                        );
                    }
                    if state.spec.looping && self.seq > 0 {
                        let period = if self.info.fps > 0.0 {
                            (1e6 / self.info.fps) as u64
                        } else {
                            33_333
                        };
                        state.loop_offset_us = state.last_ts_us + period;
                        state.loops += 1;
                        state.skip_until_us = 0;
                        tracing::info!(spec = %self.spec, loops = state.loops, "replay looping");
                        self.restart()?;
                        continue;
                    }
                    state.ended = true;
                    // Stop the player (it spins after the end) and release the file.
                    self.session = None;
                    tracing::info!(spec = %self.spec, frames = self.seq, unpaired = self.pairer.unpaired, "replay finished");
                    return Ok(None);
                }
            }
        }
    }
}
