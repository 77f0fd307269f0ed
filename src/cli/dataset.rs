//! `irsim dataset SPEC --out DIR [--shard I/N]`: the sequences a dataset spec draws, each recorded as `irsim
//! record` records a scenario, next to the scenario it was drawn as.
//!
//! Layout: `DIR/spec.toml` (the spec, as given), `DIR/sequences/seq_000042/` (`scenario.toml`, `frames/`,
//! `masks/`, `labels.jsonl`, `gt_mot.txt`, `manifest.json`) and `DIR/shards/shard-I-of-N.json` (what a shard
//! did). Shard `I` of `N` records the sequences `k` with `k mod N = I − 1`. A sequence is recorded into
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
use crate::dataset::DatasetSpec;
use crate::record::{FrameFormat, write_atomic};
use crate::scenario::load::{Format, load_str};

/// `irsim dataset`.
#[derive(Debug, clap::Args)]
pub struct DatasetArgs {
    /// The dataset spec (TOML; docs/datasets.md).
    pub spec: PathBuf,
    /// Output directory (created). Shards of one dataset share it; a directory holding another spec is refused.
    #[arg(long)]
    pub out: PathBuf,
    /// Record only shard I of N (1-based): the sequences k with k mod N = I − 1.
    #[arg(long, default_value = "1/1", value_parser = parse_shard)]
    pub shard: Shard,
    /// Record this shard's sequences again even where they are complete.
    #[arg(long)]
    pub force: bool,
    /// No progress bar.
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

/// The directory of sequence `k`.
pub fn sequence_dir(out: &Path, k: u64) -> PathBuf {
    out.join("sequences").join(format!("seq_{k:06}"))
}

/// Whether `dir` holds a complete recording (its manifest says so).
fn complete(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join("manifest.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .is_some_and(|m| m["status"] == "complete")
        && dir.join("scenario.toml").is_file()
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
    let spec_text = std::fs::read_to_string(&a.spec)
        .map_err(|e| CliError::Invalid(format!("{}: cannot read: {e}", a.spec.display())))?;
    let spec = DatasetSpec::from_str(&spec_text, &a.spec.display().to_string())
        .map_err(|e| CliError::Invalid(e.to_string()))?;
    prepare_out(&a.out, spec_text.as_bytes())?;
    let mine: Vec<u64> = (0..spec.sequences).filter(|&k| a.shard.owns(k)).collect();
    let todo: Vec<u64> = mine.iter().copied().filter(|&k| a.force || !complete(&sequence_dir(&a.out, k))).collect();
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
            record_sequence(&spec, &a.out, k, &stop, &mut |written| bar.set_position(done_before + written))?;
        if !finished {
            break;
        }
        recorded += 1;
    }
    bar.finish_and_clear();
    let interrupted = stop.load(Ordering::SeqCst) && recorded < todo.len() as u64;
    let shard_file = a.out.join("shards").join(format!("shard-{}-of-{}.json", a.shard.index, a.shard.count));
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
        a.out.display()
    );
    if interrupted {
        return Err(CliError::Interrupted);
    }
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
        write_atomic(&spec_file, spec_text).map_err(|e| CliError::Failed(e.to_string()))?;
    }
    Ok(())
}

/// Draws and records sequence `k` into its directory; false when `stop` ended it first (its partial directory
/// is left for the next run to remove).
fn record_sequence(
    spec: &DatasetSpec,
    out: &Path,
    k: u64,
    stop: &Arc<AtomicBool>,
    progress: &mut dyn FnMut(u64),
) -> Result<bool, CliError> {
    let text = spec.sequence_scenario(k).map_err(|e| CliError::Failed(format!("sequence {k}: {e}")))?;
    let scenario = load_str(&text, Format::Toml, Path::new("scenario.toml"), out).map_err(|e| {
        CliError::Failed(format!("sequence {k}: the drawn scenario is refused: {e} (please report it)"))
    })?;
    let fin = sequence_dir(out, k);
    let partial = out.join("sequences").join(format!(".seq_{k:06}.partial"));
    if partial.exists() {
        std::fs::remove_dir_all(&partial).map_err(|e| io(&partial, e))?;
    }
    let plan = RecordPlan {
        out: partial.clone(),
        first_frame: 0,
        frames: spec.frames,
        seed: None,
        force: false,
        noise: true,
        vibration: true,
        format: FrameFormat::Png16,
        masks: true,
        reproducible: true,
    };
    let done = record_scenario(&scenario, &plan, stop, &mut |written, _| progress(written))?;
    if done.interrupted {
        return Ok(false);
    }
    write_atomic(&partial.join("scenario.toml"), text.as_bytes()).map_err(|e| CliError::Failed(e.to_string()))?;
    if fin.exists() {
        std::fs::remove_dir_all(&fin).map_err(|e| io(&fin, e))?;
    }
    std::fs::rename(&partial, &fin).map_err(|e| io(&fin, e))?;
    Ok(true)
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
