//! Festival-rendered speech with its own phone timing (the ground truth of docs/lipsync.md),
//! the live analyser's profiles learned from it, and the measures of bench/lipsync_accuracy.py
//! (frames of the right class, shape class, boundary error) on the live analyser's output.
//! Shared by the `live` test and the `live_eval` example.

#![allow(dead_code)]

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use mouthpiece_frame::audio::{AudioBlock, AudioFormat};
use mouthpiece_lipsync::live::{
    learn_from_recordings, LiveAnalyser, LiveSettings, LiveStep, Profiles, Recording,
};
use mouthpiece_lipsync::phones::{self, PhoneFormat};
use mouthpiece_lipsync::take::{DEFAULT_CLASSES, DEFAULT_CLASSES_NAME};
use mouthpiece_lipsync::{ClassTable, PhoneSpan};

/// The evaluation sentences of bench/lipsync_accuracy.py: never learned from.
pub const EVALUATION: [(&str, &str); 8] = [
    (
        "sa1",
        "She had your dark suit in greasy wash water all year.",
    ),
    ("sa2", "Don't ask me to carry an oily rag like that."),
    ("s3", "The birch canoe slid on the smooth planks."),
    ("s4", "Glue the sheet to the dark blue background."),
    ("s5", "It's easy to tell the depth of a well."),
    ("s6", "Four hours of steady work faced us."),
    ("s7", "A large size in stockings is hard to sell."),
    ("s8", "The boy was there when the sun rose."),
];

/// What the shipped profiles are learned from: Harvard sentences (lists 2 to 5 and others),
/// none of them an evaluation sentence.
pub const LEARNING: [&str; 40] = [
    "The boy was there when the sun rose over the hill.",
    "A rod is used to catch pink salmon.",
    "The source of the huge river is the clear spring.",
    "Kick the ball straight and follow through.",
    "Help the woman get back to her feet.",
    "A pot of tea helps to pass the evening.",
    "Smoky fires lack flame and heat.",
    "The soft cushion broke the man's fall.",
    "The salt breeze came across from the sea.",
    "The girl at the booth sold fifty bonds.",
    "The small pup gnawed a hole in the sock.",
    "The fish twisted and turned on the bent hook.",
    "Press the pants and sew a button on the vest.",
    "The swan dive was far short of perfect.",
    "The beauty of the view stunned the young boy.",
    "Two blue fish swam in the tank.",
    "Her purse was full of useless trash.",
    "The colt reared and threw the tall rider.",
    "It snowed, rained, and hailed the same morning.",
    "Read verse out loud for pleasure.",
    "Hoist the load to your left shoulder.",
    "Take the winding path to reach the lake.",
    "Note closely the size of the gas tank.",
    "Wipe the grease off his dirty face.",
    "Mend the coat before you go out.",
    "The wrist was badly strained and hung limp.",
    "The stray cat gave birth to kittens.",
    "The young girl gave no clear response.",
    "The meal was cooked before the bell rang.",
    "What joy there is in living.",
    "A king ruled the state in the early days.",
    "The ship was torn apart on the sharp reef.",
    "Sickness kept him home the third week.",
    "The wide road shimmered in the hot sun.",
    "The lazy cow lay in the cool grass.",
    "Lift the square stone over the fence.",
    "The rope will bind the seven books at once.",
    "Hop over the fence and plunge in.",
    "The friendly gang left the drug store.",
    "Mesh wire keeps chicks inside.",
];

pub fn table() -> ClassTable {
    ClassTable::from_toml_str(DEFAULT_CLASSES, DEFAULT_CLASSES_NAME).unwrap()
}

/// A line spoken by Festival: 16 kHz mono samples and Festival's own phones.
pub struct Spoken {
    pub rate: u32,
    pub samples: Vec<i16>,
    pub phones: Vec<PhoneSpan>,
}

/// Speaks `text` with Festival (Debian `festival`, `festvox-kallpc16k`) into `dir`.
pub fn speak(text: &str, dir: &Path, name: &str) -> Spoken {
    let scm = dir.join(format!("{name}.scm"));
    let wav = dir.join(format!("{name}.wav"));
    let segs = dir.join(format!("{name}.segs"));
    std::fs::write(
        &scm,
        format!(
            "(set! u (Utterance Text \"{text}\"))\n(utt.synth u)\n(utt.save.wave u \"{}\" 'riff)\n(utt.save.segs u \"{}\")\n",
            wav.display(),
            segs.display()
        ),
    )
    .unwrap();
    let out = Command::new("festival")
        .arg("-b")
        .arg(&scm)
        .output()
        .expect("festival (Debian festival + festvox-kallpc16k) must be installed");
    assert!(
        out.status.success(),
        "festival: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut reader = hound::WavReader::open(&wav).unwrap();
    let spec = reader.spec();
    let samples: Vec<i16> = reader
        .samples::<i16>()
        .step_by(spec.channels as usize)
        .map(Result::unwrap)
        .collect();
    let text = std::fs::read_to_string(&segs).unwrap();
    let phones = phones::read(&text, PhoneFormat::Label, name).unwrap();
    Spoken {
        rate: spec.sample_rate,
        samples,
        phones,
    }
}

/// The truth class at time `t` (the last phone past the end).
pub fn truth_class(table: &ClassTable, phones: &[PhoneSpan], t: f64) -> usize {
    let p = phones
        .iter()
        .find(|p| p.start <= t && t < p.end)
        .unwrap_or(phones.last().unwrap());
    table.class_of(&p.phone).unwrap_or(table.silence())
}

/// Profiles learned from `lines` (features labelled with the class at the window's centre).
pub fn learn(table: &ClassTable, lines: &[Spoken], learned_on: &str) -> Profiles {
    let recordings: Vec<Recording> = lines
        .iter()
        .map(|l| Recording {
            samples: &l.samples,
            rate: l.rate,
            phones: &l.phones,
            name: "festival",
        })
        .collect();
    learn_from_recordings(table, &recordings, learned_on).unwrap()
}

/// `samples` at `rate` upsampled by an integer factor (linear interpolation; the content
/// stays below 8 kHz), to run a 16 kHz line through a 48 kHz analyser.
pub fn upsample(samples: &[i16], factor: usize) -> Vec<i16> {
    let mut out = Vec::with_capacity(samples.len() * factor);
    for (i, &s) in samples.iter().enumerate() {
        let next = *samples.get(i + 1).unwrap_or(&s);
        for k in 0..factor {
            let r = k as f64 / factor as f64;
            out.push((f64::from(s) * (1.0 - r) + f64::from(next) * r).round() as i16);
        }
    }
    out
}

/// Runs samples through an analyser in blocks of `block` frames; returns the steps and the
/// processing time of each block.
pub fn analyse(
    analyser: &mut LiveAnalyser,
    samples: &[i16],
    rate: u32,
    block: usize,
) -> (Vec<LiveStep>, Vec<f64>) {
    let format = AudioFormat {
        sample_rate: rate,
        channels: 1,
    };
    let mut steps = Vec::new();
    let mut times = Vec::new();
    let start = Instant::now();
    for (k, chunk) in samples.chunks(block).enumerate() {
        let b = AudioBlock {
            seq: k as u64,
            first_frame: (k * block) as u64,
            format,
            samples: chunk.to_vec(),
            host_rx: start + format.duration_of(((k + 1) * block) as u64),
            wall_clock: None,
        };
        let t0 = Instant::now();
        analyser.push(&b, &mut steps).unwrap();
        times.push(t0.elapsed().as_secs_f64());
    }
    (steps, times)
}

/// The measures of one or more lines.
#[derive(Debug, Default, Clone)]
pub struct Measures {
    pub frames: usize,
    pub class_ok: usize,
    pub shape_ok: usize,
    pub boundary_errors: Vec<f64>,
    pub runs_matched: usize,
    pub truth_runs: usize,
    /// Per matched run that is not silence: the first step giving its class minus the
    /// truth's start, seconds (how long after the sound began the analyser said so).
    pub onset_lags: Vec<f64>,
}

impl Measures {
    pub fn class_share(&self) -> f64 {
        self.class_ok as f64 / self.frames.max(1) as f64
    }
    pub fn shape_share(&self) -> f64 {
        self.shape_ok as f64 / self.frames.max(1) as f64
    }
    pub fn boundary(&self, q: f64) -> f64 {
        let mut e = self.boundary_errors.clone();
        e.sort_by(f64::total_cmp);
        if e.is_empty() {
            return f64::NAN;
        }
        e[((q * (e.len() - 1) as f64).round() as usize).min(e.len() - 1)]
    }
    pub fn lag(&self, q: f64) -> f64 {
        let mut e = self.onset_lags.clone();
        e.sort_by(f64::total_cmp);
        e.get(((q * (e.len().max(1) - 1) as f64).round()) as usize)
            .copied()
            .unwrap_or(f64::NAN)
    }
    pub fn matched_share(&self) -> f64 {
        self.runs_matched as f64 / self.truth_runs.max(1) as f64
    }
}

/// Runs of equal class: (start, end, class).
fn runs(items: impl Iterator<Item = (f64, f64, usize)>) -> Vec<(f64, f64, usize)> {
    let mut out: Vec<(f64, f64, usize)> = Vec::new();
    for (s, e, c) in items {
        match out.last_mut() {
            Some(last) if last.2 == c => last.1 = e,
            _ => out.push((s, e, c)),
        }
    }
    out
}

/// Edit-distance alignment of two class-run lists (same class 0, else 1; insertions and
/// deletions 1); the aligned pairs.
fn align(a: &[(f64, f64, usize)], b: &[(f64, f64, usize)]) -> Vec<(usize, usize)> {
    let (n, m) = (a.len(), b.len());
    let mut cost = vec![vec![0.0; m + 1]; n + 1];
    for (i, row) in cost.iter_mut().enumerate() {
        row[0] = i as f64;
    }
    for (j, c) in cost[0].iter_mut().enumerate() {
        *c = j as f64;
    }
    let sub = |i: usize, j: usize| if a[i].2 == b[j].2 { 0.0 } else { 1.0 };
    for i in 1..=n {
        for j in 1..=m {
            cost[i][j] = (cost[i - 1][j - 1] + sub(i - 1, j - 1))
                .min(cost[i - 1][j] + 1.0)
                .min(cost[i][j - 1] + 1.0);
        }
    }
    let (mut i, mut j, mut pairs) = (n, m, Vec::new());
    while i > 0 && j > 0 {
        if cost[i][j] == cost[i - 1][j - 1] + sub(i - 1, j - 1) {
            pairs.push((i - 1, j - 1));
            i -= 1;
            j -= 1;
        } else if cost[i][j] == cost[i - 1][j] + 1.0 {
            i -= 1;
        } else {
            j -= 1;
        }
    }
    pairs.reverse();
    pairs
}

/// Adds one line's measures: each step against the truth class at its time; the step's
/// class runs against the truth's class runs (boundary error over aligned same-class runs,
/// both ends).
pub fn measure(table: &ClassTable, phones: &[PhoneSpan], steps: &[LiveStep], m: &mut Measures) {
    let targets: Vec<&Vec<f64>> = table.classes.iter().map(|c| &c.target).collect();
    for s in steps {
        let truth = truth_class(table, phones, s.t);
        m.frames += 1;
        m.class_ok += usize::from(s.class == truth);
        let nearest = (0..targets.len())
            .min_by(|&a, &b| {
                let d = |k: usize| -> f64 {
                    s.weights
                        .iter()
                        .zip(targets[k])
                        .map(|(x, y)| (x - y) * (x - y))
                        .sum()
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        m.shape_ok += usize::from(nearest == truth);
    }
    let hop = steps.get(1).map_or(0.01, |s| s.t - steps[0].t);
    let live = runs(steps.iter().map(|s| (s.t - hop, s.t, s.class)));
    let truth = runs(phones.iter().map(|p| {
        (
            p.start,
            p.end,
            table.class_of(&p.phone).unwrap_or(table.silence()),
        )
    }));
    for (i, j) in align(&live, &truth) {
        if live[i].2 == truth[j].2 {
            m.runs_matched += 1;
            m.boundary_errors.push((live[i].0 - truth[j].0).abs());
            m.boundary_errors.push((live[i].1 - truth[j].1).abs());
            if truth[j].2 != table.silence() {
                m.onset_lags.push(live[i].0 + hop - truth[j].0);
            }
        }
    }
    m.truth_runs += truth.len();
}

/// A fresh analyser on the shipped class table.
pub fn analyser(profiles: &Profiles, settings: LiveSettings) -> LiveAnalyser {
    LiveAnalyser::new(table(), profiles, settings).unwrap()
}
