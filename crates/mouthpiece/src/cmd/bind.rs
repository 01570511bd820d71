//! `mouthpiece bind`: a character's mesh bound to its mouth points (skin weights, skinned
//! GLB); `bind head` makes a procedural head for a character, `bind train` trains the
//! network, `bind evaluate` measures it against the baselines.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::anyhow;
use mouthpiece_bind::network::Widths;
use mouthpiece_bind::training;
use mouthpiece_bind::{commands, BindError, Method, ModelUp};

use crate::exit::{bad_input, bad_input_if};

#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    pub action: Option<Action>,
    /// Character file (TOML): the mouth points the joints go to, and the mouth's placement.
    #[arg(long, required = true)]
    pub character: Option<PathBuf>,
    /// The mesh (glTF or GLB) in the character's model frame and units.
    #[arg(long, required = true)]
    pub mesh: Option<PathBuf>,
    /// Output: the skinned mesh as GLB.
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// How to compute the skin weights; the network by default, whatever the mesh (it
    /// wins on the mouth region of every family measured, docs/bind.md).
    #[arg(long, value_enum, default_value = "network")]
    pub method: MethodArg,
    /// Network weights (from `bind train`); the shipped network by default.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Up axis of the character's model frame: `y` (glTF's) or `z` (Blender's; the mesh
    /// file then holds it in glTF's axes, as Blender's glTF exporter writes it).
    #[arg(long, value_enum, default_value = "y")]
    pub model_up: UpArg,
    /// A mesh (or its node) that is the face, by name (repeat for several); by default the
    /// meshes nearest to the mouth points. Other meshes (eyes, teeth) follow the head rigidly.
    #[arg(long = "face-mesh")]
    pub face_mesh: Vec<String>,
    /// The node (usually a bone of the file's skeleton) the mouth's joints hang under; by
    /// default a joint named like `head`, else a new `root` node.
    #[arg(long)]
    pub parent_bone: Option<String>,
    /// The jaw's hinge `x,y,z` in the character's model frame and units; by default the
    /// character's `[rig] jaw_pivot`, else read from the face's depth below the mouth
    /// (docs/bind.md), else the rig's default behind and above the mouth.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    pub jaw_hinge: Option<[f64; 3]>,
    /// No jaw joint: the chin stays with the head.
    #[arg(long)]
    pub no_jaw: bool,
}

/// `x,y,z`: three finite numbers.
fn parse_point(text: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = text.split(',').collect();
    let numbers: Vec<f64> = parts
        .iter()
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("`{}`: {e}", mouthpiece_export::asset::shown(text)))?;
    match numbers[..] {
        [x, y, z] if numbers.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!(
            "`{}`: give three finite numbers x,y,z",
            mouthpiece_export::asset::shown(text)
        )),
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum UpArg {
    Y,
    Z,
}

impl From<UpArg> for ModelUp {
    fn from(up: UpArg) -> Self {
        match up {
            UpArg::Y => ModelUp::Y,
            UpArg::Z => ModelUp::Z,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// The trained graph network.
    Network,
    /// Heat diffusion over the surface (Blender's "automatic weights").
    Heat,
    /// Softmax of the negative distance to each point.
    Distance,
}

#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// Write a procedural head around a character's mouth (GLB, model frame and units).
    Head(HeadArgs),
    /// Train the network on procedural heads against their reference weights.
    Train(TrainArgs),
    /// Measure the network and the baselines on held-out heads (Markdown table on stdout).
    Evaluate(EvaluateArgs),
}

#[derive(Debug, clap::Args)]
pub struct HeadArgs {
    #[arg(long)]
    pub character: PathBuf,
    /// 0: a human face around the mouth; 1: a long muzzle.
    #[arg(long, default_value_t = 0.0)]
    pub snout: f64,
    /// Mesh density (12·R vertices around each ring).
    #[arg(long, default_value_t = 4)]
    pub resolution: usize,
    /// Up axis of the character's model frame (`z`: the GLB is written in glTF's axes).
    #[arg(long, value_enum, default_value = "y")]
    pub model_up: UpArg,
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// Where to write the network's weights.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed for the training heads, the initial weights and the order: same seed, same
    /// weights.
    #[arg(long)]
    pub seed: u64,
    /// Procedural heads to train on.
    #[arg(long, default_value_t = training::DEFAULT_HEADS)]
    pub heads: usize,
    #[arg(long, default_value_t = training::DEFAULT_EPOCHS)]
    pub epochs: usize,
    /// Adam's learning rate (halved for the last third of the epochs).
    #[arg(long, default_value_t = training::DEFAULT_RATE)]
    pub rate: f32,
    /// Layer widths: `paper` (first layer 64, concatenation 576), `small` (32, 160; the
    /// shipped network), `tiny` (for tests).
    #[arg(long, value_enum, default_value = "small")]
    pub widths: WidthsArg,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WidthsArg {
    Paper,
    Small,
    Tiny,
}

#[derive(Debug, clap::Args)]
pub struct EvaluateArgs {
    /// Network weights; the shipped network by default.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Held-out random heads (drawn from a seed the training never uses).
    #[arg(long, default_value_t = 8)]
    pub heads: usize,
    /// Characters whose mouths are also held out (repeat); each with a --snout.
    #[arg(long)]
    pub character: Vec<PathBuf>,
    /// Snout (0 human … 1 muzzle) of each --character's head, in order.
    #[arg(long)]
    pub snout: Vec<f64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let result = match args.action {
        Some(Action::Head(a)) => head(a),
        Some(Action::Train(a)) => train(a),
        Some(Action::Evaluate(a)) => {
            commands::evaluate(a.model.as_deref(), a.heads, &a.character, &a.snout)
                .map(|table| print!("{table}"))
        }
        None => return bind(args),
    };
    result.map_err(bind_error)
}

fn bind_error(err: BindError) -> anyhow::Error {
    bad_input_if(err.is_bad_input(), err)
}

fn bind(args: Args) -> anyhow::Result<()> {
    let (Some(character), Some(mesh), Some(out)) = (args.character, args.mesh, args.out) else {
        return Err(bad_input(anyhow!(
            "bind needs --character, --mesh and --out"
        )));
    };
    let rig = commands::load_rig(&character).map_err(bind_error)?;
    let network = match args.method {
        MethodArg::Network => {
            Some(commands::load_network(args.model.as_deref()).map_err(bind_error)?)
        }
        _ => None,
    };
    let method = match (&network, args.method) {
        (Some(network), _) => Method::Network(network),
        (None, MethodArg::Heat) => Method::Heat,
        _ => Method::Distance,
    };
    let start = Instant::now();
    let mut options = mouthpiece_bind::BindOptions::new(args.model_up.into(), method);
    options.face_meshes = args.face_mesh;
    options.parent_bone = args.parent_bone;
    options.jaw = !args.no_jaw;
    options.jaw_hinge = args.jaw_hinge;
    let summary = mouthpiece_bind::bind(&rig, &mesh, &out, &options).map_err(bind_error)?;
    eprintln!(
        "face: {} ({} vertices after merging seams, {} triangles; {})",
        summary.face.join(", "),
        summary.welded_vertices,
        summary.triangles,
        summary.topology
    );
    if summary.points_from_nodes {
        eprintln!("mouth points: the file's nodes named like the character's points");
    }
    for (part, joint) in &summary.parts {
        eprintln!("part: {part} follows {joint}");
    }
    eprintln!(
        "wrote {}: the input with a skin added, the mouth under {}; {} vertices in the file, {} follow the mouth; {:?} weights in {:.2} s",
        out.display(),
        summary.parent.as_deref().unwrap_or("a new root"),
        summary.vertices,
        summary.moving_vertices,
        args.method,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn head(args: HeadArgs) -> Result<(), BindError> {
    let up = args.model_up.into();
    let mesh = commands::write_head(&args.character, up, args.snout, args.resolution, &args.out)?;
    eprintln!(
        "wrote {}: {} vertices, {} triangles",
        args.out.display(),
        mesh.len(),
        mesh.triangles.len()
    );
    Ok(())
}

fn train(args: TrainArgs) -> Result<(), BindError> {
    let start = Instant::now();
    let request = commands::TrainRequest {
        out: args.out.clone(),
        seed: args.seed,
        heads: args.heads,
        epochs: args.epochs,
        rate: args.rate,
        widths: match args.widths {
            WidthsArg::Paper => Widths::PAPER,
            WidthsArg::Small => Widths::SMALL,
            WidthsArg::Tiny => Widths::TINY,
        },
    };
    let net = commands::train(&request, |line| eprintln!("{line}"))?;
    eprintln!(
        "wrote {}: {} parameters, {:.0} s",
        args.out.display(),
        net.parameter_count(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
