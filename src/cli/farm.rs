//! Renders that outgrow one machine or one sitting: `render --part K/N` (one share of the work),
//! `hslt merge` (any set of parts into one image), and `render --checkpoint` / `--resume` (the state so
//! far, written atomically, and the run that continues it). Parts and checkpoints are EXRs holding
//! the image, the film's sums as two more parts (`render::RenderState`) and what a merge checks.

use super::{Cli, Command, RenderArgs};
use crate::image::{read_exr_metadata, write_exr_layers, write_image, ImageBuf, Metadata};
use crate::registry::{IntegratorKind, IntegratorSettings};
use crate::render::{RenderOptions, RenderOutput, RenderState, RenderStats, Share, Work};
use crate::scene::Scene;
use crate::sensor::ReconstructionFilter;
use anyhow::{anyhow, bail, Context};
use clap::{Args, Parser};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Metadata keys of parts and checkpoints.
pub const PART_COUNT: &str = "hslt.part.count";
pub const PART_COVERS: &str = "hslt.part.covers";
pub const SCENE_HASH: &str = "hslt.scene_sha256";
pub const SETTINGS: &str = "hslt.part.settings";
const ARGS: &str = "hslt.checkpoint.args";
const SCENE: &str = "hslt.checkpoint.scene";
const ELAPSED: &str = "hslt.checkpoint.elapsed_seconds";
const SEGMENTS: &str = "hslt.checkpoint.segments";
const COMPLETE: &str = "hslt.checkpoint.complete";

/// `--part K/N`, 1 ≤ K ≤ N.
pub fn parse_part(s: &str) -> Result<Share, String> {
    let (k, n) = s.split_once('/').ok_or_else(|| format!("'{s}' is not of the form K/N (e.g. 2/8)"))?;
    let (k, n): (u32, u32) = match (k.trim().parse(), n.trim().parse()) {
        (Ok(k), Ok(n)) => (k, n),
        _ => return Err(format!("'{s}': K and N must be whole numbers")),
    };
    if n == 0 || n > 65_536 || k == 0 || k > n {
        return Err(format!("'{s}': need 1 ≤ K ≤ N ≤ 65536"));
    }
    Ok(Share { index: k - 1, count: n })
}

/// SHA-256 of what the scene's image depends on: the scene file, the `-D` values it is loaded with,
/// and every file its loaders read (`<include>`d files, meshes, textures, environment maps; call
/// after loading). Contents only, not paths, so farm nodes that mount the scene elsewhere agree.
pub fn scene_hash(path: &Path, defines: &[(String, String)]) -> anyhow::Result<String> {
    let digest = |file: &Path| -> anyhow::Result<Vec<u8>> {
        let mut hash = Sha256::new();
        let mut f = std::fs::File::open(file).with_context(|| format!("cannot read {}", file.display()))?;
        std::io::copy(&mut f, &mut hash).with_context(|| format!("cannot read {}", file.display()))?;
        Ok(hash.finalize().to_vec())
    };
    let mut hash = Sha256::new();
    hash.update(digest(path)?);
    let mut defines = defines.to_vec();
    defines.sort();
    for (k, v) in &defines {
        hash.update(format!("{}={}\n", k.len(), k).as_bytes());
        hash.update(format!("{}={}\n", v.len(), v).as_bytes());
    }
    // Sorted by content, so the order the loaders happened to read them in does not matter.
    let mut inputs =
        crate::resources::input_files().iter().map(|f| digest(f)).collect::<anyhow::Result<Vec<_>>>()?;
    inputs.sort();
    for d in inputs {
        hash.update(d);
    }
    Ok(hash.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// The options that decide what a render's samples are (not where it writes or on how many threads),
/// which the parts of one render share.
pub fn image_settings(args: &RenderArgs) -> String {
    format!(
        "integrator={:?} spp={:?} time={:?} seed={} max_depth={:?} min_depth={} mis={} seed_paths={:?} \
         seed_share={:?} chains={:?} restart_every={:?} mutations={:?} lambda={} specular_threshold={} hslt_direction={} \
         hslt_chains={} p_large={} direct_samples={:?} direct_share={:?} accel={}",
        args.integrator,
        args.spp,
        args.time,
        args.seed,
        args.max_depth,
        args.min_depth,
        args.mis,
        args.seed_paths,
        args.seed_share,
        args.chains,
        args.restart_every,
        args.mutations,
        args.lambda,
        args.specular_threshold,
        args.hslt_direction,
        args.hslt_chains,
        args.p_large,
        args.direct_samples,
        args.direct_share,
        args.accel
    )
}

/// Writes a state file: the image, the film's sums and `meta` with the state's work.
pub fn write_state(path: &Path, state: &RenderState, meta: &Metadata) -> anyhow::Result<()> {
    let mut meta = meta.clone();
    meta.extend(state.metadata().map_err(|e| anyhow!("{}: {e}", path.display()))?);
    let image = state.image();
    let layers = state.layers();
    let mut parts: Vec<(&str, &ImageBuf)> = vec![("combined", &image)];
    parts.extend(layers.iter().map(|(n, img)| (*n, img)));
    write_exr_layers(path, &parts, &meta).map(|_| ())
}

/// Replaces the values of `meta` under the given keys (appending those it lacks).
pub fn set_fields(meta: &mut Metadata, fields: Vec<(String, String)>) {
    for (key, value) in fields {
        match meta.iter_mut().find(|(k, _)| *k == key) {
            Some(entry) => entry.1 = value,
            None => meta.push((key, value)),
        }
    }
}

fn field<'a>(meta: &'a Metadata, path: &Path, key: &str) -> anyhow::Result<&'a str> {
    super::lookup(meta, key).ok_or_else(|| {
        anyhow!(
            "{}: no {key} in its metadata (expected an EXR written by `hslt render --part` or --checkpoint, \
             or by `hslt merge`)",
            path.display()
        )
    })
}

/// A checkpoint to continue: the command line it was started with and how far it got.
pub struct Checkpoint {
    pub path: PathBuf,
    /// The arguments of the original `hslt render` (after `render`).
    pub args: Vec<String>,
    pub scene: PathBuf,
    pub scene_hash: String,
    pub elapsed: f64,
    pub segments: u32,
    pub complete: bool,
}

impl Checkpoint {
    pub fn open(path: &Path) -> anyhow::Result<Checkpoint> {
        if !path.is_file() {
            bail!("--resume: {} does not exist", path.display());
        }
        let meta =
            read_exr_metadata(path).with_context(|| format!("--resume: cannot read {}", path.display()))?;
        let args_text = field(&meta, path, ARGS)?;
        let args: Vec<String> = serde_json::from_str(args_text)
            .map_err(|e| anyhow!("{}: {ARGS} is not a JSON list of arguments: {e}", path.display()))?;
        let number = |key: &str| -> anyhow::Result<f64> {
            let v = field(&meta, path, key)?;
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x >= 0.0)
                .ok_or_else(|| anyhow!("{}: {key} = {v:?} (expected a non-negative number)", path.display()))
        };
        Ok(Checkpoint {
            path: path.to_path_buf(),
            args,
            scene: PathBuf::from(field(&meta, path, SCENE)?),
            scene_hash: field(&meta, path, SCENE_HASH)?.to_string(),
            elapsed: number(ELAPSED)?,
            segments: number(SEGMENTS)? as u32,
            complete: field(&meta, path, COMPLETE)? == "true",
        })
    }

    /// The original render's arguments, with this invocation's outputs and run options (threads,
    /// progress, memory cap, live view, checkpoint file and interval) in place of the original's.
    pub fn render_args(&self, now: &RenderArgs) -> anyhow::Result<RenderArgs> {
        // Options that decide the image come from the checkpoint; given anew they would be ignored.
        let bare =
            Cli::try_parse_from(["hslt", "render", "--resume", "x.exr", "-o", "x.exr"]).ok().and_then(|c| {
                match c.command {
                    Command::Render(args) => Some(image_settings(&args)),
                    _ => None,
                }
            });
        if bare.is_some_and(|bare| bare != image_settings(now)) {
            bail!(
                "--resume takes the render's options from {}; give only outputs and run options (--threads, -q, --checkpoint, --max-memory, --tev, --stats-json)",
                self.path.display()
            );
        }
        let argv = std::iter::once("hslt".to_string()).chain(self.args.iter().cloned());
        let cli = Cli::try_parse_from(argv).map_err(|e| {
            anyhow!("{}: its recorded command line no longer parses: {}", self.path.display(), e.render())
        })?;
        let Command::Render(args) = cli.command else {
            bail!("{}: its recorded command line is not `hslt render`", self.path.display());
        };
        let mut args = *args;
        args.scene = Some(self.scene.clone());
        args.output = now.output.clone();
        args.threads = now.threads;
        args.quiet = now.quiet;
        args.memory = now.memory.clone();
        args.tev = now.tev.clone();
        args.stats_json = now.stats_json.clone();
        args.checkpoint = Some(now.checkpoint.clone().unwrap_or_else(|| self.path.clone()));
        args.checkpoint_every = now.checkpoint_every;
        args.resume = Some(self.path.clone());
        Ok(args)
    }

    /// The state so far, after checking the scene is the one the checkpoint was rendered from.
    pub fn state(&self, scene_hash: &str, rfilter: ReconstructionFilter) -> anyhow::Result<RenderState> {
        if scene_hash != self.scene_hash {
            bail!(
                "{}: the scene {} has changed since this checkpoint was written (its SHA-256 and -D values \
                 differ); render it anew",
                self.path.display(),
                self.scene.display()
            );
        }
        RenderState::read(&self.path, rfilter)
    }
}

/// The metadata a checkpoint adds to a render's.
pub fn checkpoint_fields(
    args: &[String],
    scene: &Path,
    elapsed: f64,
    segments: u32,
    complete: bool,
) -> Vec<(String, String)> {
    vec![
        (ARGS.into(), serde_json::to_string(args).unwrap_or_default()),
        (SCENE.into(), scene.display().to_string()),
        (ELAPSED.into(), format!("{elapsed:.3}")),
        (SEGMENTS.into(), segments.to_string()),
        (COMPLETE.into(), complete.to_string()),
    ]
}

/// `hslt merge`: parts of one render into one image.
#[derive(Args, Debug)]
pub struct MergeArgs {
    /// Parts written by `hslt render --part K/N` (or merges of them): any subset of one render's
    /// parts, each at most once.
    #[arg(required = true, value_name = "PART")]
    pub parts: Vec<PathBuf>,
    /// Output image(s); an .exr keeps the sums, so it can be merged again with the missing parts.
    #[arg(short, long = "output", required = true)]
    pub output: Vec<PathBuf>,
    /// No summary.
    #[arg(short, long)]
    pub quiet: bool,
}

/// One part as read for merging.
struct Part {
    path: PathBuf,
    meta: Metadata,
    covers: Vec<u32>,
    count: u32,
}

/// Fields that must agree between the parts of one render.
const MUST_AGREE: [&str; 6] =
    [SCENE_HASH, "hslt.integrator", "hslt.seed", "hslt.width", "hslt.height", SETTINGS];

pub fn run_merge(args: MergeArgs) -> anyhow::Result<i32> {
    super::check_output_paths(&args.output)?;
    let mut parts = Vec::new();
    for path in &args.parts {
        let meta =
            read_exr_metadata(path).with_context(|| format!("cannot read the part {}", path.display()))?;
        let count: u32 = field(&meta, path, PART_COUNT)?
            .parse()
            .map_err(|_| anyhow!("{}: {PART_COUNT} is not a number", path.display()))?;
        let covers = field(&meta, path, PART_COVERS)?
            .split(',')
            .map(|k| k.trim().parse::<u32>().ok().filter(|&k| k >= 1 && k <= count))
            .collect::<Option<Vec<u32>>>()
            .ok_or_else(|| anyhow!("{}: {PART_COVERS} is not a list of parts 1..{count}", path.display()))?;
        parts.push(Part { path: path.clone(), meta, covers, count });
    }
    let first = &parts[0];
    let mut covered = vec![None::<&Path>; first.count as usize];
    for part in &parts {
        for key in MUST_AGREE {
            let (a, b) = (super::lookup(&first.meta, key), super::lookup(&part.meta, key));
            if a.is_none() || a != b {
                bail!(
                    "{} and {} are not parts of one render: their {key} differ ({} against {})",
                    first.path.display(),
                    part.path.display(),
                    a.unwrap_or("missing"),
                    b.unwrap_or("missing")
                );
            }
        }
        if part.count != first.count {
            bail!(
                "{} is a part of {} and {} of {}: parts of one render have the same N",
                first.path.display(),
                first.count,
                part.path.display(),
                part.count
            );
        }
        for &k in &part.covers {
            if let Some(other) = covered[k as usize - 1] {
                bail!(
                    "part {k}/{} is in both {} and {}: merging it twice would count its samples twice",
                    first.count,
                    other.display(),
                    part.path.display()
                );
            }
            covered[k as usize - 1] = Some(&part.path);
        }
    }
    let mut merged: Option<RenderState> = None;
    for part in &parts {
        let state = RenderState::read(&part.path, ReconstructionFilter::Box)?;
        match merged.as_mut() {
            None => merged = Some(state),
            Some(m) => m.absorb(&state).map_err(|e| anyhow!("{}: {e}", part.path.display()))?,
        }
    }
    let merged = merged.expect("at least one part");
    let covers: Vec<u32> = (1..=first.count).filter(|k| covered[*k as usize - 1].is_some()).collect();
    let missing: Vec<String> =
        (1..=first.count).filter(|k| covered[*k as usize - 1].is_none()).map(|k| k.to_string()).collect();
    let mut meta = first.meta.clone();
    // One part's run statistics would pass for the merge's: drop them, and add up the counts.
    const PER_RUN: [&str; 6] = [
        "hslt.samples_per_second",
        "hslt.cpu_seconds",
        "hslt.peak_memory_bytes",
        "hslt.threads",
        "hslt.resumed_segments",
        "hslt.part",
    ];
    meta.retain(|(k, _)| {
        !k.starts_with("hslt.state.")
            && !k.starts_with("hslt.checkpoint.")
            && !k.starts_with("hslt.mlt.")
            && !PER_RUN.contains(&k.as_str())
    });
    let sum = |key: &str| -> u64 {
        parts.iter().filter_map(|p| super::lookup(&p.meta, key)?.parse::<u64>().ok()).sum()
    };
    let seconds: f64 = parts
        .iter()
        .filter_map(|p| super::lookup(&p.meta, "hslt.elapsed_seconds")?.parse::<f64>().ok())
        .sum();
    let interrupted = parts.iter().any(|p| super::lookup(&p.meta, "hslt.interrupted") == Some("true"));
    let spp = match merged.work {
        Work::Pixels { spp } => spp,
        Work::Chains { .. } => sum("hslt.spp"),
    };
    set_fields(
        &mut meta,
        vec![
            (PART_COVERS.into(), covers.iter().map(u32::to_string).collect::<Vec<_>>().join(",")),
            ("hslt.part".into(), format!("merge of {} of {}", covers.len(), first.count)),
            ("hslt.spp".into(), spp.to_string()),
            ("hslt.samples".into(), sum("hslt.samples").to_string()),
            ("hslt.rays".into(), sum("hslt.rays").to_string()),
            ("hslt.shadow_rays".into(), sum("hslt.shadow_rays").to_string()),
            ("hslt.closest_hit_rays".into(), sum("hslt.closest_hit_rays").to_string()),
            ("hslt.invalid_samples".into(), sum("hslt.invalid_samples").to_string()),
            ("hslt.elapsed_seconds".into(), format!("{seconds:.3}")),
            ("hslt.interrupted".into(), interrupted.to_string()),
        ],
    );
    for out in &args.output {
        let is_exr =
            out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() == Some("exr");
        if is_exr { write_state(out, &merged, &meta) } else { write_image(out, &merged.image(), &meta) }
            .with_context(|| format!("cannot write {}", out.display()))?;
    }
    if !args.quiet {
        eprintln!(
            "merged {} file(s): parts {} of {}{}",
            parts.len(),
            covers.iter().map(u32::to_string).collect::<Vec<_>>().join(","),
            first.count,
            if missing.is_empty() {
                String::new()
            } else {
                format!(" (missing {}: the image holds their share of the work less)", missing.join(","))
            }
        );
        for o in &args.output {
            eprintln!("wrote {}", o.display());
        }
    }
    Ok(0)
}

/// Refuses a part that would get no work: a pixel integrator's share of fewer samples per pixel than
/// parts, or a Metropolis render split into more parts than it has chains.
pub(super) fn check_part(
    kind: IntegratorKind,
    share: Share,
    options: &RenderOptions,
    settings: &IntegratorSettings,
) -> anyhow::Result<()> {
    let n = share.count as u64;
    match kind {
        IntegratorKind::Path | IntegratorKind::Bdpt => {
            if let Some(spp) = options.spp.filter(|&spp| (spp as u64) < n) {
                bail!("--part K/{n}: {spp} samples per pixel cannot be split into {n} parts (use --spp {n} or more)");
            }
        }
        _ => {
            let chains = match kind {
                IntegratorKind::Pssmlt => settings.pssmlt.chains,
                _ => settings.path_chains.unwrap_or(crate::metropolis::mlt::DEFAULT_PATH_CHAINS),
            };
            if (chains as u64) < n {
                bail!(
                    "--part K/{n}: {chains} chains cannot be split into {n} parts (use --chains {n} or more)"
                );
            }
        }
    }
    Ok(())
}

/// The options of a run that continues `state`, the work a checkpoint recorded, towards what
/// `options` asked for in all; `None` when nothing is left. A pixel integrator takes the sample
/// indices after those already taken, so the two runs are exactly one; a Metropolis one starts new
/// chains on streams of their own (the segment number is mixed into its seeds).
pub(super) fn continued_options(
    options: &RenderOptions,
    state: &RenderState,
    checkpoint: &Checkpoint,
    scene: &Scene,
) -> Option<RenderOptions> {
    let mut run = options.clone();
    if let Some(limit) = options.time_limit {
        let left = limit.as_secs_f64() - checkpoint.elapsed;
        if left <= 0.0 {
            return None;
        }
        run.time_limit = Some(Duration::from_secs_f64(left));
    }
    match state.work {
        Work::Pixels { spp: done } => {
            run.share = Share::WHOLE;
            match options.spp {
                Some(spp) => {
                    let mine = options.share.range(spp as u64);
                    let left = (mine.end - mine.start).checked_sub(done).filter(|&n| n > 0)?;
                    run.first_sample = (mine.start + done) as u32;
                    run.spp = Some(left as u32);
                }
                None => {
                    run.seed = options.share.stream_seed(options.seed);
                    run.first_sample = done as u32;
                }
            }
        }
        Work::Chains { mutations, .. } => {
            run.first_sample = checkpoint.segments.max(1);
            run.mutations_done = mutations;
            if options.spp.is_some() && crate::metropolis::driver::total_mutations(&run, scene) == 0 {
                return None;
            }
        }
    }
    Some(run)
}

/// The output of a run that had nothing left to do.
pub(super) fn nothing_left(scene: &Scene, earlier: Option<&RenderState>) -> RenderOutput {
    let work = match earlier.map(|e| e.work) {
        Some(Work::Chains { .. }) => Work::Chains { mutations: 0, b_sum: 0.0, b_samples: 0 },
        _ => Work::Pixels { spp: 0 },
    };
    let film = crate::render::Film::with_filter(scene.film.width, scene.film.height, scene.film.rfilter);
    RenderOutput { film, stats: RenderStats::default(), metadata: Vec::new(), work }
}

/// Writes checkpoints of one render: the earlier runs' state (when resumed) with this run's so far.
#[derive(Clone)]
pub(super) struct CheckpointWriter {
    pub path: PathBuf,
    pub earlier: Option<RenderState>,
    /// The render's metadata without its work (which comes from the state at each write).
    pub meta: Metadata,
    pub command_line: Vec<String>,
    pub scene: PathBuf,
    pub elapsed_before: f64,
    pub segments: u32,
}

impl CheckpointWriter {
    /// Writes `now` (added to the earlier runs' state) after `elapsed` seconds of this run; `extra`
    /// replaces metadata fields (the final write passes the render's whole metadata).
    pub fn write(
        &self,
        now: &RenderState,
        elapsed: f64,
        complete: bool,
        extra: &Metadata,
    ) -> anyhow::Result<()> {
        let mut state = now.clone();
        if let Some(e) = &self.earlier {
            let mut total = e.clone();
            total.absorb(now).map_err(|err| anyhow!("{err}"))?;
            state = total;
        }
        let pixels = (state.film.width * state.film.height).max(1) as u64;
        let (spp, samples) = match state.work {
            Work::Pixels { spp } => (spp, spp * pixels),
            Work::Chains { mutations, .. } => (mutations / pixels, mutations),
        };
        let total_elapsed = self.elapsed_before + elapsed;
        let mut meta = self.meta.clone();
        set_fields(&mut meta, extra.clone());
        set_fields(
            &mut meta,
            vec![
                ("hslt.spp".into(), spp.to_string()),
                ("hslt.samples".into(), samples.to_string()),
                ("hslt.elapsed_seconds".into(), format!("{total_elapsed:.3}")),
                ("hslt.interrupted".into(), (!complete).to_string()),
            ],
        );
        set_fields(
            &mut meta,
            checkpoint_fields(&self.command_line, &self.scene, total_elapsed, self.segments, complete),
        );
        write_state(&self.path, &state, &meta)
    }
}
