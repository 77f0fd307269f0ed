//! `irsim dataset SPEC --out DIR [--shard I/N]`: the sequences a dataset spec draws, each recorded as `irsim
//! record` records a scenario, next to the scenario it was drawn as; `irsim dataset merge DIR`: the
//! dataset-level exports (`crate::dataset::merge`), which a single-shard run also builds at its end.
//!
//! Layout: `DIR/spec.toml` (the spec, as given), `DIR/sequences/seq_000042/` (`scenario.toml`, `frames/`,
//! `masks/`, `labels.jsonl`, `gt_mot.txt`, `manifest.json`) and, until the merge, `DIR/shards/shard-I-of-N.json`
//! (what a shard did). Shard `I` of `N` records the sequences `k` with `k mod N = I − 1`. A sequence is recorded into
//! `DIR/sequences/.seq_000042.partial/` and renamed into place when complete, so a sequence directory is
//! always whole, shards never write the same files, and a shard run again (after pre-emption) skips the
//! sequences already there. The recordings' manifests hold no timings, so a sequence is the same bytes on any
//! machine and in any shard.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde_json::json;

use super::CliError;
use super::run::{RecordPlan, record_scenario, stop_flag_and_bar};
use crate::dataset::merge::{MergeError, complete, merge, sequence_dir};
use crate::dataset::solve::solve;
use crate::dataset::{DatasetSpec, SKY_IMAGE_EXTENSIONS, SkyFile};
use crate::record::{FrameFormat, write_atomic, write_shared};
use crate::scenario::load::{Format, load_str};

/// `irsim dataset`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct DatasetArgs {
    /// `merge DIR`: build the exports of a dataset whose shards are done.
    #[command(subcommand)]
    pub command: Option<DatasetCommand>,
    /// The dataset spec (TOML; docs/datasets.md).
    #[arg(required = true)]
    pub spec: Option<PathBuf>,
    /// Output directory (created). Shards of one dataset share it; a directory holding another spec is refused.
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// Record only shard I of N (1-based): the sequences k with k mod N = I − 1.
    #[arg(long, default_value = "1/1", value_parser = parse_shard)]
    pub shard: Shard,
    /// Record this shard's sequences again even where they are complete.
    #[arg(long)]
    pub force: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// With a single shard (1/1): record only, without building the exports (`irsim dataset merge` later).
    #[arg(long)]
    pub no_merge: bool,
}

/// `irsim dataset merge`.
#[derive(Debug, clap::Subcommand)]
pub enum DatasetCommand {
    /// Build COCO, YOLO, SIRST masks, MOTChallenge, the split, the card and the checksums of a dataset whose
    /// sequences are all recorded (by any number of shards); reports the shards still to run.
    Merge(MergeArgs),
}

/// `irsim dataset merge DIR`.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The dataset's directory (the `--out` its shards wrote to).
    pub dir: PathBuf,
    /// No progress messages.
    #[arg(long)]
    pub quiet: bool,
}

/// Shard `index` (1-based) of `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// 1 … count.
    pub index: u64,
    /// At least 1.
    pub count: u64,
}

impl Shard {
    /// Whether sequence `k` is this shard's.
    pub fn owns(&self, k: u64) -> bool {
        k % self.count == self.index - 1
    }
}

fn parse_shard(s: &str) -> Result<Shard, String> {
    let bad = || format!("`{s}` is not I/N with 1 ≤ I ≤ N (e.g. 3/8)");
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let (index, count): (u64, u64) = (i.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
    if count == 0 || index == 0 || index > count {
        return Err(bad());
    }
    Ok(Shard { index, count })
}

fn io(what: &Path, e: std::io::Error) -> CliError {
    CliError::Failed(format!("{}: {e}", what.display()))
}

/// `irsim dataset SPEC --out DIR`.
///
/// # Errors
/// [`CliError::Invalid`] (exit 2) for a bad spec or an output directory holding something else;
/// [`CliError::Failed`] for a write error; [`CliError::Interrupted`] on Ctrl-C.
pub fn dataset(a: &DatasetArgs) -> Result<(), CliError> {
    if let Some(DatasetCommand::Merge(m)) = &a.command {
        return merge_dir(&m.dir, m.quiet);
    }
    let (Some(spec_path), Some(out)) = (&a.spec, &a.out) else {
        return Err(CliError::Invalid("irsim dataset SPEC --out DIR, or irsim dataset merge DIR".into()));
    };
    let spec_text = std::fs::read_to_string(spec_path)
        .map_err(|e| CliError::Invalid(format!("{}: cannot read: {e}", spec_path.display())))?;
    let spec = DatasetSpec::from_str(&spec_text, &spec_path.display().to_string())
        .map_err(|e| CliError::Invalid(e.to_string()))?;
    let out = out.as_path();
    let found = find_skies(&spec, &spec_text, spec_path)?;
    prepare_out(out, spec_text.as_bytes())?;
    let skies = copy_skies(found, out)?;
    let mine: Vec<u64> = (0..spec.sequences).filter(|&k| a.shard.owns(k)).collect();
    let todo: Vec<u64> = mine.iter().copied().filter(|&k| a.force || !complete(&sequence_dir(out, k))).collect();
    let (stop, bar) = stop_flag_and_bar(a.quiet, todo.len() as u64 * spec.frames);
    let started = Instant::now();
    let mut recorded = 0u64;
    for (n, &k) in todo.iter().enumerate() {
        if stop.load(Ordering::SeqCst) {
            break;
        }
        bar.set_message(format!("sequence {k} ({} of {})", n + 1, todo.len()));
        let done_before = n as u64 * spec.frames;
        let finished =
            record_sequence(&spec, out, k, &skies, &stop, &mut |written| bar.set_position(done_before + written))?;
        if !finished {
            break;
        }
        recorded += 1;
    }
    bar.finish_and_clear();
    let interrupted = stop.load(Ordering::SeqCst) && recorded < todo.len() as u64;
    let shard_file = out.join("shards").join(format!("shard-{}-of-{}.json", a.shard.index, a.shard.count));
    let status = if interrupted { "interrupted" } else { "complete" };
    let record = json!({
        "dataset": spec.name,
        "shard": a.shard.index,
        "of": a.shard.count,
        "status": status,
        "sequences": mine,
    });
    write_atomic(&shard_file, format!("{record:#}\n").as_bytes()).map_err(|e| CliError::Failed(e.to_string()))?;
    let elapsed = started.elapsed().as_secs_f64();
    eprintln!(
        "{status}: shard {}/{} of `{}`: {recorded} sequences recorded, {} already complete, {} frames in {elapsed:.1} s ({:.1} frames/s) under {}",
        a.shard.index,
        a.shard.count,
        spec.name,
        mine.len() - todo.len(),
        recorded * spec.frames,
        (recorded * spec.frames) as f64 / elapsed.max(1e-9),
        out.display()
    );
    if interrupted {
        return Err(CliError::Interrupted);
    }
    if a.shard.count == 1 && !a.no_merge {
        merge_dir(out, a.quiet)
    } else {
        eprintln!("when every shard is done: irsim dataset merge {}", out.display());
        Ok(())
    }
}

/// `irsim dataset merge DIR`.
fn merge_dir(dir: &Path, quiet: bool) -> Result<(), CliError> {
    let spec_path = dir.join("spec.toml");
    let spec_text = std::fs::read_to_string(&spec_path).map_err(|e| {
        CliError::Invalid(format!(
            "{}: cannot read ({e}): is {} a dataset's directory?",
            spec_path.display(),
            dir.display()
        ))
    })?;
    let spec = DatasetSpec::from_str(&spec_text, &spec_path.display().to_string())
        .map_err(|e| CliError::Invalid(e.to_string()))?;
    let started = Instant::now();
    let say = |m: &str| {
        if !quiet {
            eprintln!("merge: {m}");
        }
    };
    let done = merge(dir, &spec, &say).map_err(|e| match e {
        MergeError::Corrupt(m) => CliError::Invalid(m),
        MergeError::Incomplete(m) | MergeError::Io(m) => CliError::Failed(m),
    })?;
    eprintln!(
        "merged `{}`: {} frames, {} annotations, {} files checksummed in {:.1} s; the card is {}",
        spec.name,
        done.frames,
        done.annotations,
        done.files,
        started.elapsed().as_secs_f64(),
        dir.join("README.md").display()
    );
    Ok(())
}

/// Creates `out` with the spec in it, or accepts it when it holds the same spec (another shard, or an earlier
/// run of this one); anything else there is refused.
fn prepare_out(out: &Path, spec_text: &[u8]) -> Result<(), CliError> {
    let spec_file = out.join("spec.toml");
    if out.exists() {
        if !out.is_dir() {
            return Err(CliError::Invalid(format!("--out {} is not a directory", out.display())));
        }
        match std::fs::read(&spec_file) {
            Ok(existing) if existing == spec_text => {}
            Ok(_) => {
                return Err(CliError::Invalid(format!(
                    "{} holds a dataset of another spec ({}); give another --out",
                    out.display(),
                    spec_file.display()
                )));
            }
            Err(_) => {
                let empty = std::fs::read_dir(out).map_err(|e| io(out, e))?.next().is_none();
                if !empty {
                    return Err(CliError::Invalid(format!(
                        "--out {} is not empty and holds no dataset (no spec.toml); give an empty or new directory",
                        out.display()
                    )));
                }
            }
        }
    }
    for dir in [out.to_path_buf(), out.join("sequences"), out.join("shards")] {
        std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
    }
    if !spec_file.exists() {
        write_shared(&spec_file, spec_text).map_err(|e| CliError::Failed(e.to_string()))?;
    }
    Ok(())
}

/// The images of the spec's sky folder (`sky.images.folder`, relative to the spec) with their paths, in name
/// order, each decoded once to check it.
fn find_skies(spec: &DatasetSpec, text: &str, spec_path: &Path) -> Result<Vec<(SkyFile, PathBuf)>, CliError> {
    let Some(images) = &spec.sky.images else { return Ok(Vec::new()) };
    let file = spec_path.display().to_string();
    let bad = |m: String| CliError::Invalid(DatasetSpec::error_at(text, &file, "sky.images.folder", m).to_string());
    let folder = spec_path.parent().unwrap_or(Path::new(".")).join(&images.folder);
    let listing = std::fs::read_dir(&folder).map_err(|e| bad(format!("{}: cannot read: {e}", folder.display())))?;
    let mut names = Vec::new();
    for entry in listing {
        let entry = entry.map_err(|e| bad(format!("{}: {e}", folder.display())))?;
        let path = entry.path();
        let known = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| SKY_IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        if known && path.is_file() {
            let name = entry.file_name().into_string().map_err(|n| bad(format!("{n:?}: not a UTF-8 file name")))?;
            if name.starts_with('.') || name.contains(['"', '\\']) || name.chars().any(char::is_control) {
                return Err(bad(format!("{}: rename it without quotes, backslashes or a leading dot", path.display())));
            }
            names.push(name);
        }
    }
    names.sort();
    if names.is_empty() {
        return Err(bad(format!(
            "{} holds no image ({})",
            folder.display(),
            SKY_IMAGE_EXTENSIONS.map(|e| format!(".{e}")).join(", ")
        )));
    }
    let mut found = Vec::new();
    for name in names {
        let path = folder.join(&name);
        let image = crate::imaging::sky_plane::SkyImage::load(&path).map_err(|e| bad(e.to_string()))?;
        found.push((SkyFile { name, width: image.width(), height: image.height() }, path));
    }
    Ok(found)
}

/// Copies the sky images into `out/skies/`, which the sequences' scenarios name; a copy already there must be
/// the same bytes (a dataset is made from one set of images).
fn copy_skies(found: Vec<(SkyFile, PathBuf)>, out: &Path) -> Result<Vec<SkyFile>, CliError> {
    let mut skies = Vec::new();
    let dir = out.join("skies");
    if !found.is_empty() {
        std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
    }
    for (sky, source) in found {
        let bytes = std::fs::read(&source).map_err(|e| io(&source, e))?;
        let copy = dir.join(&sky.name);
        match std::fs::read(&copy) {
            Ok(there) if there == bytes => {}
            Ok(_) => {
                return Err(CliError::Invalid(format!(
                    "{} is not the same image as {}: {} was made with other sky images; give another --out",
                    copy.display(),
                    source.display(),
                    out.display()
                )));
            }
            Err(_) => write_shared(&copy, &bytes).map_err(|e| CliError::Failed(e.to_string()))?,
        }
        skies.push(sky);
    }
    Ok(skies)
}

/// Draws and records sequence `k` into its directory, with the extra frames the spec asks for; false when
/// `stop` ended it first (its partial directory is left for the next run to remove).
fn record_sequence(
    spec: &DatasetSpec,
    out: &Path,
    k: u64,
    skies: &[SkyFile],
    stop: &Arc<AtomicBool>,
    progress: &mut dyn FnMut(u64),
) -> Result<bool, CliError> {
    let fin = sequence_dir(out, k);
    // the partial directory is as deep as the final one: the scenario's relative paths (`../../skies/…`) hold
    // in both
    let partial = out.join("sequences").join(format!(".seq_{k:06}.partial"));
    if partial.exists() {
        std::fs::remove_dir_all(&partial).map_err(|e| io(&partial, e))?;
    }
    std::fs::create_dir_all(&partial).map_err(|e| io(&partial, e))?;
    let solved = solve(spec, k, skies, &partial).map_err(|e| CliError::Failed(format!("sequence {k}: {e}")))?;
    let text = solved.drawn.scenario();
    let plan = RecordPlan {
        out: partial.clone(),
        first_frame: 0,
        frames: spec.frames,
        seed: None,
        force: false,
        noise: true,
        vibration: true,
        format: FrameFormat::Png16,
        png: spec.png_compression,
        masks: true,
        reproducible: true,
    };
    if !record_drawn(&text, k, &partial, &plan, stop, progress)? {
        return Ok(false);
    }
    // the extra frames: recorded apart, their frames kept beside the sequence's
    let extras = [(spec.outputs.noise_free, "noise_free", false), (spec.outputs.clean_background, "clean", true)];
    for (wanted, name, background) in extras {
        if !wanted {
            continue;
        }
        let scenario = if background { solved.drawn.background() } else { text.clone() };
        let run_dir = partial.join(format!(".{name}"));
        let extra = RecordPlan { out: run_dir.clone(), noise: false, masks: false, ..plan.clone() };
        if !record_drawn(&scenario, k, &partial, &extra, stop, &mut |_| {})? {
            return Ok(false);
        }
        std::fs::rename(run_dir.join("frames"), partial.join(name)).map_err(|e| io(&partial.join(name), e))?;
        std::fs::remove_dir_all(&run_dir).map_err(|e| io(&run_dir, e))?;
    }
    if !solved.targets.is_empty() {
        let targets: Vec<_> = solved
            .targets
            .iter()
            .enumerate()
            .map(|(i, t)| {
                json!({ "id": i + 1, "asked": t.asked, "reached": t.reached, "range_m": t.range_m, "limit": t.limit })
            })
            .collect();
        let record = json!({ "frame": solved.drawn.middle_frame, "iterations": solved.iterations, "targets": targets });
        write_atomic(&partial.join("snr_solve.json"), format!("{record:#}\n").as_bytes())
            .map_err(|e| CliError::Failed(e.to_string()))?;
    }
    write_atomic(&partial.join("scenario.toml"), text.as_bytes()).map_err(|e| CliError::Failed(e.to_string()))?;
    if fin.exists() {
        std::fs::remove_dir_all(&fin).map_err(|e| io(&fin, e))?;
    }
    std::fs::rename(&partial, &fin).map_err(|e| io(&fin, e))?;
    Ok(true)
}

/// Records the drawn scenario `text` of sequence `k` as `plan` says, its relative paths resolved in `base`;
/// false when `stop` ended it first.
fn record_drawn(
    text: &str,
    k: u64,
    base: &Path,
    plan: &RecordPlan,
    stop: &Arc<AtomicBool>,
    progress: &mut dyn FnMut(u64),
) -> Result<bool, CliError> {
    let scenario = load_str(text, Format::Toml, Path::new("scenario.toml"), base).map_err(|e| {
        CliError::Failed(format!("sequence {k}: the drawn scenario is refused: {e} (please report it)"))
    })?;
    let done = record_scenario(&scenario, plan, stop, &mut |written, _| progress(written))?;
    Ok(!done.interrupted)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_the_sequences() {
        assert_eq!(parse_shard("2/3"), Ok(Shard { index: 2, count: 3 }));
        for bad in ["0/3", "4/3", "1/0", "x/2", "3", "-1/2"] {
            assert!(parse_shard(bad).is_err(), "{bad}");
        }
        // every sequence in exactly one shard, for any count
        for count in 1..6 {
            for k in 0..50 {
                let owners = (1..=count).filter(|&index| Shard { index, count }.owns(k)).count();
                assert_eq!(owners, 1, "sequence {k}, {count} shards");
            }
        }
    }
}
