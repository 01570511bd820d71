//! `mouthpiece takes list|fetch`: the takes every booth uploaded to the studio's NATS
//! object store (docs/nats.md). The servers, credentials, TLS and studio come from the
//! config's `[nats]`; `--server` and `--studio` override them.

use std::path::PathBuf;

use anyhow::Context as _;
use mouthpiece_config::Config;
use mouthpiece_nats::store::{partial_path, TakeRecord, TakeStore};
use mouthpiece_nats::NatsSettings;
use mouthpiece_output::shown;

use crate::exit::bad_input;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub action: Action,
    /// Config file whose `[nats]` says where the store is (default: the system config when
    /// there is one).
    #[arg(long, value_name = "FILE", global = true)]
    pub config: Option<PathBuf>,
    /// A NATS server, overriding the config's (repeat for a cluster).
    #[arg(long, value_name = "URL", global = true)]
    pub server: Vec<String>,
    /// The studio (its buckets), overriding the config's.
    #[arg(long, value_name = "NAME", global = true)]
    pub studio: Option<String>,
}

#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// List the takes in the store: booth, slate, take, timecode, length, frames,
    /// characters and the object's name.
    List {
        /// Only this booth's takes.
        #[arg(long)]
        booth: Option<String>,
        /// One JSON record per line instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Copy takes from the store into a folder (written whole, never over an existing file).
    Fetch {
        /// Objects as `list` shows them (`<booth>/<file>.mcap`).
        #[arg(required = true)]
        objects: Vec<String>,
        /// Where the files go.
        #[arg(long, default_value = ".")]
        out: PathBuf,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let settings = settings(&args)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        let client = mouthpiece_nats::connect_once(&settings).await?;
        let store = TakeStore::open_existing(&client, &settings.studio).await?;
        match args.action {
            Action::List { booth, json } => list(&store, booth.as_deref(), json).await,
            Action::Fetch { objects, out } => fetch(&store, &objects, &out).await,
        }
    })
}

fn settings(args: &Args) -> anyhow::Result<NatsSettings> {
    let system = PathBuf::from(mouthpiece_config::SYSTEM_CONFIG_PATH);
    let config = match &args.config {
        Some(path) => Config::load(path).map_err(bad_input)?,
        None if system.exists() => Config::load(&system).map_err(bad_input)?,
        None => Config::embedded(),
    };
    let mut settings = match NatsSettings::from_config(&config.nats) {
        Some(settings) => settings,
        None => NatsSettings::new(Vec::new(), ""),
    };
    if !args.server.is_empty() {
        for server in &args.server {
            if server.contains('@') {
                return Err(bad_input(anyhow::anyhow!(
                    "--server: credentials in a URL are refused; put them in the config's [nats]"
                )));
            }
        }
        settings.servers = args.server.clone();
    }
    if settings.servers.is_empty() {
        return Err(bad_input(anyhow::anyhow!(
            "no NATS server: give --server nats://HOST:PORT or a --config with [nats] servers"
        )));
    }
    mouthpiece_nats::server_addrs(&settings.servers)
        .map_err(|e| bad_input(anyhow::anyhow!("--server: {e}")))?;
    if let Some(studio) = &args.studio {
        if !mouthpiece_config::subject_safe(studio) {
            return Err(bad_input(anyhow::anyhow!(
                "--studio: expected 1 to 64 letters, digits, '-' or '_', got {}",
                mouthpiece_config::quote_excerpt(studio)
            )));
        }
        settings.studio = studio.clone();
    }
    Ok(settings)
}

async fn list(store: &TakeStore, booth: Option<&str>, json: bool) -> anyhow::Result<()> {
    let records: Vec<TakeRecord> = store
        .list()
        .await?
        .into_iter()
        .filter(|r| booth.is_none_or(|b| r.booth == b))
        .collect();
    if json {
        for record in &records {
            println!("{}", serde_json::to_string(record)?);
        }
        return Ok(());
    }
    println!("booth\tslate\ttake\ttimecode\tseconds\tframes\tcharacters\tobject");
    for r in &records {
        // Every text comes from the store: escaped, so that a tab, a newline or an escape
        // sequence cannot forge a column, a row or the terminal's state.
        let characters: Vec<_> = r.characters.iter().map(|c| shown(c)).collect();
        println!(
            "{}\t{}\t{}\t{}\t{:.2}\t{}\t{}\t{}",
            shown(&r.booth),
            shown(&r.slate),
            r.take,
            shown(&r.timecode),
            r.duration_s,
            r.frames,
            characters.join(","),
            shown(&r.object)
        );
    }
    eprintln!("{} takes", records.len());
    Ok(())
}

async fn fetch(store: &TakeStore, objects: &[String], out: &std::path::Path) -> anyhow::Result<()> {
    if !out.is_dir() {
        return Err(bad_input(anyhow::anyhow!(
            "--out: {} is not a folder",
            out.display()
        )));
    }
    // Every name is checked before anything is fetched.
    let mut targets = Vec::new();
    for object in objects {
        let file = object.rsplit('/').next().unwrap_or_default();
        if file.is_empty() || file == "." || file == ".." || !file.ends_with(".mcap") {
            return Err(bad_input(anyhow::anyhow!(
                "{}: expected an object as `takes list` shows it (<booth>/<file>.mcap)",
                mouthpiece_config::quote_excerpt(object)
            )));
        }
        let path = out.join(file);
        // Any entry counts, a dangling symbolic link too (`exists` follows links).
        let taken = |p: &std::path::Path| std::fs::symlink_metadata(p).is_ok();
        if taken(&path) || taken(&partial_path(&path)) {
            return Err(bad_input(anyhow::anyhow!(
                "{} exists: not overwritten",
                path.display()
            )));
        }
        targets.push((object, path));
    }
    for (object, path) in targets {
        let bytes = store.fetch(object, &path).await.map_err(|e| match e {
            // The store's contents are at fault, not the network: bad input.
            e @ mouthpiece_nats::NatsError::Untrusted { .. } => bad_input(e),
            e => e.into(),
        })?;
        println!("{} ({bytes} bytes)", path.display());
    }
    Ok(())
}
