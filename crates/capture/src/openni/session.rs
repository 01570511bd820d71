//! Opening an OpenNI2 device or file: the modes picked, the streams made and started (with
//! OpenNI2's recorder on them when recording), and the calibration delivered frames carry.

use super::*;

pub(super) fn describe(err: &openni2::Error) -> String {
    match err.status() {
        Some(status) if status.name() == "NO_DEVICE" => format!("no such device ({err})"),
        _ => err.to_string(),
    }
}

pub(super) fn pick_mode(
    modes: &[VideoMode],
    formats: &[PixelFormat],
    config: &CaptureConfig,
) -> Option<VideoMode> {
    modes
        .iter()
        .filter(|m| formats.contains(&m.pixel_format))
        .copied()
        .min_by_key(|m| {
            let format_rank = formats
                .iter()
                .position(|f| *f == m.pixel_format)
                .unwrap_or(formats.len());
            (
                (m.width as i64 - config.width as i64).abs()
                    + (m.height as i64 - config.height as i64).abs(),
                (m.fps as i64 - config.fps as i64).abs(),
                format_rank,
            )
        })
}

pub(super) const DEPTH_FORMATS: [PixelFormat; 2] =
    [PixelFormat::DEPTH_1_MM, PixelFormat::DEPTH_100_UM];
pub(super) const COLOR_FORMATS: [PixelFormat; 3] =
    [PixelFormat::RGB888, PixelFormat::YUYV, PixelFormat::YUV422];

pub(super) fn fov_of(k: &Intrinsics) -> (f64, f64) {
    (
        2.0 * (k.width as f64 / 2.0 / k.fx).atan(),
        2.0 * (k.height as f64 / 2.0 / k.fy).atan(),
    )
}

/// Opens a device and its streams, agrees on modes, starts streaming.
pub(super) fn open_session(
    spec: &str,
    uri: &str,
    is_file: bool,
    config: &CaptureConfig,
    record_to: Option<&Path>,
) -> Result<(Session, Negotiated, String, Option<Recorder>), SourceError> {
    let device = Device::open(uri).map_err(|e| {
        let hint = if is_file {
            "OpenNI2's file driver could not open it".to_string()
        } else {
            "is it plugged in, and not in use by another process?".to_string()
        };
        open_error_with(
            spec,
            format!(
                "cannot open OpenNI2 device {uri:?}: {} ({hint})",
                describe(&e)
            ),
            e,
        )
    })?;
    let description = format!(
        "{} {} ({})",
        device.info().vendor,
        device.info().name,
        device.info().uri
    );
    let call = |what: &str, e: openni2::Error| open_error_with(spec, format!("{what}: {e}"), e);
    if is_file {
        device
            .set_playback_speed(-1.0)
            .map_err(|e| call("cannot set manual playback", e))?;
        device
            .set_playback_repeat(false)
            .map_err(|e| call("cannot turn playback repeat off", e))?;
    }
    let has = |sensor| {
        device
            .sensor_modes(sensor)
            .map_err(|e| call("cannot list sensor modes", e))
    };
    let depth_modes = has(SensorType::Depth)?
        .ok_or_else(|| open_error(spec, "the device has no depth sensor"))?;
    let color_modes = has(SensorType::Color)?
        .ok_or_else(|| open_error(spec, "the device has no colour sensor"))?;
    let depth = device
        .create_stream(SensorType::Depth)
        .map_err(|e| call("cannot create the depth stream", e))?;
    let color = device
        .create_stream(SensorType::Color)
        .map_err(|e| call("cannot create the colour stream", e))?;
    if !is_file {
        for (stream, modes, formats) in [
            (&depth, &depth_modes, &DEPTH_FORMATS[..]),
            (&color, &color_modes, &COLOR_FORMATS[..]),
        ] {
            let Some(mode) = pick_mode(modes, formats, config) else {
                continue;
            };
            if stream.video_mode().ok() == Some(mode) {
                continue;
            }
            // Some drivers (the Dummy) have one fixed mode and refuse the call; the mode
            // actually in use is read back below either way.
            if let Err(err) = stream.set_video_mode(mode) {
                tracing::warn!(sensor = %stream.sensor(), %mode, %err, "mode refused; keeping the device's");
            }
        }
        for s in [&depth, &color] {
            if let Err(err) = s.set_mirroring(false) {
                tracing::warn!(%err, sensor = %s.sensor(), "cannot turn mirroring off");
            }
        }
    }
    // What the device agreed to, not what was asked.
    let depth_mode = depth
        .video_mode()
        .map_err(|e| call("the depth stream reports no mode", e))?;
    let color_mode = color
        .video_mode()
        .map_err(|e| call("the colour stream reports no mode", e))?;
    if !DEPTH_FORMATS.contains(&depth_mode.pixel_format) {
        return Err(format_error(
            spec,
            format!(
                "unsupported depth pixel format {} (supported: DEPTH_1_MM, DEPTH_100_UM)",
                depth_mode.pixel_format
            ),
        ));
    }
    if !COLOR_FORMATS.contains(&color_mode.pixel_format) {
        return Err(format_error(
            spec,
            format!(
                "unsupported colour pixel format {} (supported: RGB888, YUYV, YUV422)",
                color_mode.pixel_format
            ),
        ));
    }

    let mut hardware_registration = false;
    if !is_file {
        match device.supports_registration() {
            Ok(true) => match device.set_registration(true) {
                Ok(()) => hardware_registration = true,
                Err(err) => {
                    tracing::warn!(%err, "hardware registration refused; registering in software")
                }
            },
            Ok(false) => {
                tracing::info!("device cannot register depth to colour; registering in software")
            }
            Err(err) => tracing::warn!(%err, "cannot query registration support"),
        }
        if let Err(err) = device.enable_depth_color_sync() {
            tracing::debug!(%err, "depth/colour frame sync not available");
        }
    }
    let fov = |s: &Stream, what: &str| -> Result<(f64, f64), SourceError> {
        Ok(
            match s
                .field_of_view()
                .map_err(|e| call("cannot read the field of view", e))?
            {
                Some((h, v)) => (h as f64, v as f64),
                None => {
                    tracing::warn!(stream = what, "no field of view reported; assuming 58°x45° (set intrinsics in the config)");
                    DEFAULT_FOV_RAD
                }
            },
        )
    };
    let depth_fov = fov(&depth, "depth")?;
    let color_fov = fov(&color, "colour")?;
    let color_k = config.color_intrinsics.unwrap_or_else(|| {
        Intrinsics::from_fov(
            color_mode.width,
            color_mode.height,
            color_fov.0,
            color_fov.1,
        )
    });
    let calibration = if hardware_registration {
        Calibration::registered(color_k)
    } else {
        let depth_k = config.depth_intrinsics.unwrap_or_else(|| {
            Intrinsics::from_fov(
                depth_mode.width,
                depth_mode.height,
                depth_fov.0,
                depth_fov.1,
            )
        });
        Calibration {
            color: color_k,
            depth: depth_k,
            depth_to_color: config.depth_to_color.unwrap_or(Extrinsics::IDENTITY),
            depth_scale_m: 0.001,
            depth_registered: false,
        }
    };

    // The recorder goes on before the streams start, so that it gets both streams' first
    // frames: OpenNI2 rewrites each stream's timestamps from its own first recorded frame,
    // and a recorder that missed one would shift depth against colour by a frame.
    let recorder = match record_to {
        Some(path) => {
            let err = |what: &str, e: openni2::Error| SourceError::Open {
                spec: path.display().to_string(),
                message: format!("{what}: {e}"),
                cause: Some(Box::new(e)),
            };
            let mut recorder =
                Recorder::create(path).map_err(|e| err("cannot create the .oni recorder", e))?;
            recorder
                .attach(&depth, false)
                .map_err(|e| err("cannot record the depth stream", e))?;
            recorder
                .attach(&color, false)
                .map_err(|e| err("cannot record the colour stream", e))?;
            recorder
                .start()
                .map_err(|e| err("cannot start recording", e))?;
            // Returns once the recorder's thread has taken the start: frames from here on
            // are recorded.
            tracing::info!(file = %path.display(), "recording .oni with OpenNI2's recorder");
            Some(recorder)
        }
        None => None,
    };
    depth
        .start()
        .map_err(|e| call("cannot start the depth stream", e))?;
    color
        .start()
        .map_err(|e| call("cannot start the colour stream", e))?;
    let overflow = if is_file {
        Overflow::Backpressure
    } else {
        Overflow::DropOldest
    };
    let reader = FrameReader::start(&[&depth, &color], READER_CAPACITY, overflow)
        .map_err(|e| call("cannot start reading frames", e))?;
    tracing::info!(
        %spec, device = %description, depth = %depth_mode, color = %color_mode,
        registration = if hardware_registration { "hardware" } else { "software" },
        "OpenNI2 source open"
    );
    let negotiated = Negotiated {
        depth_mode,
        color_mode,
        software_registration: !hardware_registration,
        calibration: Calibration {
            depth_registered: true,
            ..calibration.clone()
        },
        depth_fov: if config.depth_intrinsics.is_some() {
            fov_of(&calibration.depth)
        } else {
            depth_fov
        },
        color_fov: if config.color_intrinsics.is_some() {
            fov_of(&calibration.color)
        } else {
            color_fov
        },
    };
    // `negotiated.calibration` describes the frames handed out: depth on the colour grid.
    let negotiated = Negotiated {
        calibration: calibration_out(&calibration),
        ..negotiated
    };
    Ok((
        Session {
            reader,
            depth,
            color,
            _device: device,
        },
        negotiated,
        description,
        recorder,
    ))
}

/// The calibration of delivered frames: depth registered onto the colour grid.
pub(super) fn calibration_out(native: &Calibration) -> Calibration {
    Calibration {
        color: native.color,
        depth: native.color,
        depth_to_color: Extrinsics::IDENTITY,
        depth_scale_m: native.depth_scale_m,
        depth_registered: true,
    }
}
