//! Source specs: `replay:PATH[?loop=1&speed=1.0&start=S]`, `openni2:[URI]`,
//! `v4l2:COLOUR_NODE[+DEPTH_NODE]`.

use std::fmt;
use std::path::PathBuf;

/// Slowest replay speed (`speed=`): slower would make frame gaps overflow a `Duration`.
pub const MIN_SPEED: f64 = 0.001;
/// Fastest paced replay speed; `speed=0` is unpaced.
pub const MAX_SPEED: f64 = 1000.0;
/// Latest replay start (`start=`), seconds: a year.
pub const MAX_START_S: f64 = 365.0 * 86_400.0;

/// A parsed source spec.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceSpec {
    Replay(ReplaySpec),
    /// `None`: the first device OpenNI2 lists.
    OpenNi2 {
        uri: Option<String>,
    },
    V4l2 {
        color: PathBuf,
        depth: Option<PathBuf>,
    },
}

/// How to play a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySpec {
    pub path: PathBuf,
    /// Start over at the end.
    pub looping: bool,
    /// Multiple of recorded speed; `None`: unpaced (as fast as frames can be read, none
    /// dropped), written `speed=0`.
    pub speed: Option<f64>,
    /// Seconds from the start of the recording to begin at.
    pub start_s: f64,
}

impl ReplaySpec {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        ReplaySpec {
            path: path.into(),
            looping: false,
            speed: Some(1.0),
            start_s: 0.0,
        }
    }

    /// An unpaced, non-looping replay (batch work, tests).
    pub fn unpaced(path: impl Into<PathBuf>) -> Self {
        ReplaySpec {
            speed: None,
            ..ReplaySpec::new(path)
        }
    }
}

/// Why a spec did not parse.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("bad source spec {spec:?}: {reason} (expected replay:PATH[?loop=1&speed=1.0&start=0], openni2:[URI] or v4l2:COLOUR_NODE[+DEPTH_NODE])")]
pub struct SpecError {
    pub spec: String,
    pub reason: String,
}

impl SourceSpec {
    pub fn parse(spec: &str) -> Result<SourceSpec, SpecError> {
        let err = |reason: String| SpecError {
            spec: spec.to_string(),
            reason,
        };
        let (scheme, rest) = spec
            .split_once(':')
            .ok_or_else(|| err("no scheme before ':'".into()))?;
        match scheme {
            "replay" => {
                let (path, query) = match rest.rsplit_once('?') {
                    Some((p, q)) => (p, Some(q)),
                    None => (rest, None),
                };
                if path.is_empty() {
                    return Err(err("replay needs a file path".into()));
                }
                let mut replay = ReplaySpec::new(path);
                for pair in query
                    .into_iter()
                    .flat_map(|q| q.split('&'))
                    .filter(|p| !p.is_empty())
                {
                    let (key, value) = pair
                        .split_once('=')
                        .ok_or_else(|| err(format!("option {pair:?} is not key=value")))?;
                    match key {
                        "loop" => {
                            replay.looping = match value {
                                "1" | "true" | "yes" => true,
                                "0" | "false" | "no" => false,
                                _ => return Err(err(format!("loop={value:?}: expected 1 or 0"))),
                            }
                        }
                        "speed" => {
                            let s: f64 = value
                                .parse()
                                .map_err(|_| err(format!("speed={value:?}: expected a number")))?;
                            if !(s == 0.0 || (MIN_SPEED..=MAX_SPEED).contains(&s)) {
                                return Err(err(format!(
                                    "speed={value}: expected 0 (unpaced) or a number from {MIN_SPEED} to {MAX_SPEED}"
                                )));
                            }
                            replay.speed = if s == 0.0 { None } else { Some(s) };
                        }
                        "start" => {
                            let s: f64 = value.parse().map_err(|_| {
                                err(format!("start={value:?}: expected seconds from the start"))
                            })?;
                            if !(0.0..=MAX_START_S).contains(&s) {
                                return Err(err(format!(
                                    "start={value}: expected seconds from 0 to {MAX_START_S}"
                                )));
                            }
                            replay.start_s = s;
                        }
                        _ => {
                            return Err(err(format!(
                                "unknown replay option {key:?} (known: loop, speed, start)"
                            )))
                        }
                    }
                }
                Ok(SourceSpec::Replay(replay))
            }
            "openni2" => Ok(SourceSpec::OpenNi2 {
                uri: (!rest.is_empty()).then(|| rest.to_string()),
            }),
            "v4l2" => {
                let (color, depth) = match rest.split_once('+') {
                    Some((c, d)) => (c, Some(d)),
                    None => (rest, None),
                };
                if color.is_empty() {
                    return Err(err("v4l2 needs a colour node, e.g. v4l2:/dev/video0".into()));
                }
                if depth == Some("") {
                    return Err(err(
                        "nothing after '+': expected a depth node, e.g. +/dev/video2".into(),
                    ));
                }
                Ok(SourceSpec::V4l2 {
                    color: PathBuf::from(color),
                    depth: depth.map(PathBuf::from),
                })
            }
            other => Err(err(format!("unknown source kind {other:?}"))),
        }
    }
}

impl fmt::Display for SourceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceSpec::Replay(r) => {
                write!(f, "replay:{}", r.path.display())?;
                let mut opts = Vec::new();
                if r.looping {
                    opts.push("loop=1".to_string());
                }
                match r.speed {
                    None => opts.push("speed=0".into()),
                    Some(s) if s != 1.0 => opts.push(format!("speed={s}")),
                    Some(_) => {}
                }
                if r.start_s > 0.0 {
                    opts.push(format!("start={}", r.start_s));
                }
                if !opts.is_empty() {
                    write!(f, "?{}", opts.join("&"))?;
                }
                Ok(())
            }
            SourceSpec::OpenNi2 { uri } => write!(f, "openni2:{}", uri.as_deref().unwrap_or("")),
            SourceSpec::V4l2 { color, depth } => {
                write!(f, "v4l2:{}", color.display())?;
                if let Some(d) = depth {
                    write!(f, "+{}", d.display())?;
                }
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_kind() {
        assert_eq!(
            SourceSpec::parse("replay:recordings/demo.mcap").unwrap(),
            SourceSpec::Replay(ReplaySpec::new("recordings/demo.mcap"))
        );
        let SourceSpec::Replay(r) =
            SourceSpec::parse("replay:a b/take.oni?loop=1&speed=2.5&start=3").unwrap()
        else {
            panic!()
        };
        assert_eq!(
            (r.path, r.looping, r.speed, r.start_s),
            (PathBuf::from("a b/take.oni"), true, Some(2.5), 3.0)
        );
        let SourceSpec::Replay(r) = SourceSpec::parse("replay:x.mcap?speed=0").unwrap() else {
            panic!()
        };
        assert_eq!(r.speed, None);
        assert_eq!(
            SourceSpec::parse("openni2:").unwrap(),
            SourceSpec::OpenNi2 { uri: None }
        );
        assert_eq!(
            SourceSpec::parse("openni2:Dummy").unwrap(),
            SourceSpec::OpenNi2 {
                uri: Some("Dummy".into())
            }
        );
        assert_eq!(
            SourceSpec::parse("openni2:1d27/0601@1/5").unwrap(),
            SourceSpec::OpenNi2 {
                uri: Some("1d27/0601@1/5".into())
            }
        );
        assert_eq!(
            SourceSpec::parse("v4l2:/dev/video4+/dev/video2").unwrap(),
            SourceSpec::V4l2 {
                color: "/dev/video4".into(),
                depth: Some("/dev/video2".into())
            }
        );
        assert_eq!(
            SourceSpec::parse("v4l2:/dev/video0").unwrap(),
            SourceSpec::V4l2 {
                color: "/dev/video0".into(),
                depth: None
            }
        );
    }

    #[test]
    fn display_round_trips() {
        for s in [
            "replay:t.mcap",
            "replay:t.oni?loop=1&speed=0&start=2",
            "openni2:",
            "openni2:Dummy",
            "v4l2:/dev/a+/dev/b",
        ] {
            assert_eq!(SourceSpec::parse(s).unwrap().to_string(), s);
        }
    }

    #[test]
    fn bad_specs_say_what_is_wrong() {
        for (spec, needle) in [
            ("demo.mcap", "no scheme"),
            ("kinect:0", "unknown source kind \"kinect\""),
            ("replay:", "needs a file path"),
            ("replay:x.mcap?loop=maybe", "loop=\"maybe\""),
            ("replay:x.mcap?speed=-1", "speed=-1"),
            ("replay:x.mcap?speed=fast", "speed=\"fast\""),
            ("replay:x.mcap?start=-2", "start=-2"),
            ("replay:x.mcap?start=1e300", "start=1e300"),
            ("replay:x.mcap?speed=1e-300", "speed=1e-300"),
            ("replay:x.mcap?speed=1e300", "speed=1e300"),
            ("replay:x.mcap?rewind=1", "unknown replay option \"rewind\""),
            ("replay:x.mcap?loop", "not key=value"),
            ("v4l2:", "needs a colour node"),
            ("v4l2:/dev/video0+", "expected a depth node"),
        ] {
            let err = SourceSpec::parse(spec).unwrap_err().to_string();
            assert!(err.contains(needle), "{spec}: {err}");
            assert!(err.contains(spec), "{spec}: {err}");
        }
    }
}
