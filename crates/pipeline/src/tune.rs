//! The paint check's work on frames and on the configuration file: propose colour ranges
//! from a few seconds of camera frames and count what the ranges in use and the proposed ones
//! find on the same frames; write a proposal into a configuration file's `[detect]` table,
//! checked to load first. The daemon's console runs it on a thread of its own and shows it.

use std::path::Path;

use mouthpiece_detect::tune::{CheckedProposal, ColourSampler, TuneOptions};
use mouthpiece_detect::{ColorClass, DetectConfig, DetectError, DotRole};
use mouthpiece_frame::{DepthImage, Frame};

use crate::setup::SetupError;

/// Why sampling or checking a proposal failed.
#[derive(Debug, thiserror::Error)]
pub enum TuneError {
    #[error("frame {seq}")]
    Frame {
        seq: u64,
        #[source]
        source: DetectError,
    },
    #[error("no frames arrived while sampling (is the camera up?)")]
    NoFrames,
    #[error("checking the proposal")]
    Check(#[source] DetectError),
}

/// Why a proposal could not be written into the configuration file (nothing is written).
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error("reading {file}")]
    Read {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{file} does not parse")]
    Parse {
        file: String,
        #[source]
        source: toml_edit::TomlError,
    },
    #[error("{file}: detect is not a table")]
    NotATable { file: String },
    #[error("the new ranges do not load (nothing written)")]
    Load(#[source] mouthpiece_config::ConfigError),
    #[error("the new ranges do not pass the checks (nothing written)")]
    Check(#[source] Box<SetupError>),
    #[error("resolving {file}")]
    Resolve {
        file: String,
        #[source]
        source: std::io::Error,
    },
    /// `file` names the link's target too when the file is a link.
    #[error("writing {file}")]
    Write {
        file: String,
        #[source]
        source: std::io::Error,
    },
}

/// Samples `frames` and checks a proposal against the ranges `detect` uses, for a performer
/// wearing `lip_dots` and `forehead_dots`.
pub fn sample_and_check(
    detect: &DetectConfig,
    lip_dots: usize,
    forehead_dots: usize,
    frames: impl IntoIterator<Item = Frame>,
) -> Result<CheckedProposal, TuneError> {
    let options = TuneOptions::from_config(detect, lip_dots, forehead_dots);
    let mut sampler = ColourSampler::new(options);
    let mut registered = DepthImage::new(0, 0);
    for frame in frames {
        sampler
            .add_frame(
                &frame.color,
                sampling_depth(&frame, &mut registered),
                frame.calibration.color.fx,
            )
            .map_err(|source| TuneError::Frame {
                seq: frame.seq,
                source,
            })?;
    }
    if sampler.frames() == 0 {
        return Err(TuneError::NoFrames);
    }
    sampler.propose_checked(detect).map_err(TuneError::Check)
}

/// The frame's depth registered to its colour image, with its scale, for the colour sampler;
/// `None` when the frame carries no usable depth (the background is then not masked).
/// `registered` is the buffer kept between frames for cameras that do not register depth.
pub fn sampling_depth<'a>(
    frame: &'a Frame,
    registered: &'a mut DepthImage,
) -> Option<(&'a DepthImage, f64)> {
    let calib = &frame.calibration;
    let depth = if calib.depth_registered {
        &frame.depth
    } else {
        mouthpiece_track::camera::register_depth(&frame.depth, calib, registered);
        &*registered
    };
    let has_depth = depth.width == frame.color.width
        && depth.height == frame.color.height
        && depth.data.iter().any(|&d| d != 0);
    has_depth.then_some((depth, calib.depth_scale_m))
}

/// A dot role as the configuration file writes it.
pub fn role_name(role: DotRole) -> &'static str {
    match role {
        DotRole::Lip => "lip",
        DotRole::Forehead => "forehead",
        DotRole::Any => "any",
    }
}

/// Replaces the file's `[[detect.class]]` entries with `classes`, keeping everything else as
/// written; checks the result loads and sets the live pipeline up before writing it
/// (atomically: a new file renamed over).
pub fn write_classes(path: &Path, classes: &[ColorClass]) -> Result<(), WriteError> {
    let shown = || path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| WriteError::Read {
        file: shown(),
        source,
    })?;
    let mut doc: toml_edit::DocumentMut = text.parse().map_err(|source| WriteError::Parse {
        file: shown(),
        source,
    })?;
    let detect = doc
        .entry("detect")
        .or_insert_with(|| toml_edit::Item::Table(toml_edit::Table::new()));
    let Some(detect) = detect.as_table_like_mut() else {
        return Err(WriteError::NotATable { file: shown() });
    };
    let mut array = toml_edit::ArrayOfTables::new();
    for c in classes {
        let mut t = toml_edit::Table::new();
        t["name"] = toml_edit::value(c.name.as_str());
        t["role"] = toml_edit::value(role_name(c.role));
        let mut hue = toml_edit::Array::new();
        for [lo, hi] in &c.hue {
            hue.push(toml_edit::Array::from_iter([
                i64::from(*lo),
                i64::from(*hi),
            ]));
        }
        t["hue"] = toml_edit::value(hue);
        let pair = |p: [u8; 2]| toml_edit::Array::from_iter([i64::from(p[0]), i64::from(p[1])]);
        t["saturation"] = toml_edit::value(pair(c.saturation));
        t["value"] = toml_edit::value(pair(c.value));
        array.push(t);
    }
    detect.insert("class", toml_edit::Item::ArrayOfTables(array));
    let new_text = doc.to_string();
    // What is written must load and pass the checks the reload makes.
    let config = mouthpiece_config::Config::parse(&new_text, path).map_err(WriteError::Load)?;
    crate::setup::setup(&config).map_err(|e| WriteError::Check(Box::new(e)))?;
    // A link stays a link: the file written is the link's final target (what a technician
    // who linked a shared booth file into place expects to change), replaced by a rename in
    // its own folder.
    let target = std::fs::canonicalize(path).map_err(|source| WriteError::Resolve {
        file: shown(),
        source,
    })?;
    let dir = target.parent().unwrap_or(Path::new("/"));
    let tmp = dir.join(format!(
        ".{}.tune-{}",
        target.file_name().unwrap_or_default().to_string_lossy(),
        std::process::id()
    ));
    let written = || -> std::io::Result<()> {
        use std::io::Write as _;
        use std::os::unix::fs::OpenOptionsExt as _;
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .custom_flags(libc::O_NOFOLLOW)
            .open(&tmp)?;
        if let Ok(meta) = std::fs::metadata(&target) {
            file.set_permissions(meta.permissions())?;
        }
        file.write_all(new_text.as_bytes())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, &target)
    };
    written().map_err(|source| {
        // Only a file this call created (it is created new).
        if source.kind() != std::io::ErrorKind::AlreadyExists {
            let _ = std::fs::remove_file(&tmp);
        }
        let file = if target == path {
            shown()
        } else {
            format!("{} (the target of {})", target.display(), shown())
        };
        WriteError::Write { file, source }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A configuration file that is a symbolic link stays one: the new ranges go to its
    /// target, written beside the target, and nothing is left in either folder.
    #[test]
    fn writing_classes_through_a_symbolic_link_writes_its_target() {
        let shared = tempfile::tempdir().unwrap();
        let etc = tempfile::tempdir().unwrap();
        let target = shared.path().join("booth-a.toml");
        std::fs::write(
            &target,
            "# booth A\n[source]\nspec = \"replay:x.mcap\"\n\n[detect]\nmin_area_px = 3\n",
        )
        .unwrap();
        let link = etc.path().join("mouthpiece.toml");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let classes = vec![ColorClass {
            name: "lip".into(),
            role: DotRole::Lip,
            hue: vec![[0, 8]],
            saturation: [100, 255],
            value: [50, 255],
        }];
        write_classes(&link, &classes).unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink(),
            "the link was replaced by a file"
        );
        assert_eq!(std::fs::read_link(&link).unwrap(), target);
        let written = std::fs::read_to_string(&target).unwrap();
        assert!(
            written.contains("# booth A") && written.contains("\"lip\""),
            "{written}"
        );
        assert_eq!(std::fs::read_dir(shared.path()).unwrap().count(), 1);
        assert_eq!(std::fs::read_dir(etc.path()).unwrap().count(), 1);
    }

    #[test]
    fn writing_classes_keeps_the_rest_of_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mouthpiece.toml");
        let text = "# booth A\n[source]\nspec = \"replay:x.mcap\" # the rehearsal\n\n\
                    [detect]\nmin_area_px = 3\n\n[[detect.class]]\nname = \"old\"\nrole = \"any\"\n\
                    hue = [[40, 80]]\nsaturation = [90, 255]\nvalue = [40, 255]\n";
        std::fs::write(&path, text).unwrap();
        let classes = vec![ColorClass {
            name: "lip".into(),
            role: DotRole::Lip,
            hue: vec![[0, 8], [172, 179]],
            saturation: [100, 255],
            value: [50, 255],
        }];
        write_classes(&path, &classes).unwrap();
        let written = std::fs::read_to_string(&path).unwrap();
        assert!(
            written.contains("# booth A") && written.contains("# the rehearsal"),
            "{written}"
        );
        assert!(written.contains("min_area_px = 3"), "{written}");
        assert!(!written.contains("\"old\""), "{written}");
        let config = mouthpiece_config::Config::parse(&written, &path).unwrap();
        let pipeline = crate::PipelineConfig::from_text(config.text().unwrap()).unwrap();
        assert_eq!(pipeline.detect.classes, classes);
        // Ranges the detector refuses are not written.
        let bad = vec![ColorClass {
            hue: vec![[170, 10]],
            ..classes[0].clone()
        }];
        let err = write_classes(&path, &bad).unwrap_err().to_string();
        assert!(err.contains("nothing written"), "{err}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), written);
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no file left behind"
        );
    }
}
