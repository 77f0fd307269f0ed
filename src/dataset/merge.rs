//! `irsim dataset merge DIR`: the dataset-level files built from the recorded sequences — the split, COCO,
//! YOLO, SIRST-style masks, MOTChallenge, the dataset card, the manifest and the checksums of every file.
//!
//! Everything here is a function of the sequences' files and the spec alone (no timings, no dates, no machine
//! names), in the order of the sequence index, so a dataset recorded by one process and one recorded by any
//! number of shards merge to the same bytes. The exports are built in `DIR/.merge.partial/` and moved into
//! place when complete; a merge that stops part way leaves the sequences as they were.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Read as _;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde_json::{Value, json};
use sha2::{Digest, Sha256};

use super::{DatasetSpec, Set, TargetClass};
use crate::labels::FrameLabels;

/// Why a merge could not finish.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// Sequences are missing or unfinished: which, and which shards to run again.
    #[error("{0}")]
    Incomplete(String),
    /// A sequence's files are not what a recording writes.
    #[error("{0}")]
    Corrupt(String),
    /// A read or write failed.
    #[error("{0}")]
    Io(String),
}

fn io(path: &Path, e: impl std::fmt::Display) -> MergeError {
    MergeError::Io(format!("{}: {e}", path.display()))
}

/// The directory of sequence `k` under the dataset directory `out`.
pub fn sequence_dir(out: &Path, k: u64) -> PathBuf {
    out.join("sequences").join(sequence_name(k))
}

/// `seq_000042`.
pub fn sequence_name(k: u64) -> String {
    format!("seq_{k:06}")
}

/// Whether `dir` holds a complete recording (its manifest says so, and its scenario is there).
pub fn complete(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join("manifest.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .is_some_and(|m| m["status"] == "complete")
        && dir.join("scenario.toml").is_file()
}

/// What a merge made.
#[derive(Debug, Clone)]
pub struct MergeSummary {
    /// Frames in the dataset.
    pub frames: u64,
    /// Annotations (targets in frame).
    pub annotations: u64,
    /// Files listed in `checksums.sha256`.
    pub files: u64,
}

/// One target in one frame, as every export writes it.
#[derive(Debug, Clone)]
struct Annotation {
    track_id: u32,
    class: usize,
    /// `[x, y, w, h]`, px, 0-based, rounded to 1e-3 as the MOT file has it.
    bbox: [f64; 4],
    /// Pixels the mask gives this target (the box's area where the mask has none: a target hidden by a nearer one).
    area: f64,
    /// COCO's uncompressed RLE of the target's mask pixels, column-major, starting with a run of zeros.
    rle: Vec<u64>,
    snr: f64,
    scr: f64,
    range_m: f64,
    altitude_m: f64,
    peak_dn: f64,
    local_contrast: f64,
    apparent_temp_k: f64,
    detectable: bool,
}

/// One frame of one sequence.
#[derive(Debug, Clone)]
struct FrameEntry {
    frame: u64,
    t_s: f64,
    annotations: Vec<Annotation>,
}

/// One sequence as read back, and the files its exports link to.
#[derive(Debug)]
struct SequenceEntry {
    k: u64,
    set: Set,
    width: u32,
    height: u32,
    sensor: String,
    frames: Vec<FrameEntry>,
}

/// The class index (in [`TargetClass::ALL`]) of a target named `class_i` by the dataset's drawing.
fn class_of(name: &str) -> Option<usize> {
    let stem = name.rsplit_once('_').map_or(name, |(s, i)| if i.parse::<u32>().is_ok() { s } else { name });
    TargetClass::ALL.iter().position(|c| c.name == stem)
}

/// Round to 1e-3 (the MOT file's precision), without a negative zero.
fn milli(v: f64) -> f64 {
    let r = (v * 1000.0).round() / 1000.0;
    if r == 0.0 { 0.0 } else { r }
}

/// COCO's uncompressed RLE of the sorted column-major indices `idx` in an image of `len` pixels.
fn rle(idx: &[u64], len: u64) -> Vec<u64> {
    let mut counts = Vec::new();
    let mut at = 0u64;
    let mut i = 0;
    while i < idx.len() {
        let start = idx[i];
        let mut end = start + 1;
        i += 1;
        while i < idx.len() && idx[i] == end {
            end += 1;
            i += 1;
        }
        counts.push(start - at);
        counts.push(end - start);
        at = end;
    }
    counts.push(len - at);
    counts
}

/// Reads a sequence: its labels, its masks (each target's pixels) and its camera; writes each frame's SIRST
/// binary mask into `stage` while its mask is decoded.
fn read_sequence(out: &Path, stage: &Path, spec: &DatasetSpec, k: u64, set: Set) -> Result<SequenceEntry, MergeError> {
    let dir = sequence_dir(out, k);
    let labels_path = dir.join("labels.jsonl");
    let text = std::fs::read_to_string(&labels_path).map_err(|e| io(&labels_path, e))?;
    let labels: Vec<FrameLabels> = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            serde_json::from_str(l).map_err(|e| {
                let what = e.to_string();
                let what = what.split(" at line ").next().unwrap_or(&what);
                MergeError::Corrupt(format!("{}:{}:{}: {what}", labels_path.display(), i + 1, e.column()))
            })
        })
        .collect::<Result<_, _>>()?;
    if labels.len() as u64 != spec.frames {
        return Err(MergeError::Corrupt(format!(
            "{}: {} frames labelled, the spec has {}",
            labels_path.display(),
            labels.len(),
            spec.frames
        )));
    }
    let scenario_path = dir.join("scenario.toml");
    let scenario = std::fs::read_to_string(&scenario_path).map_err(|e| io(&scenario_path, e))?;
    let sensor = scenario
        .parse::<toml::Table>()
        .ok()
        .and_then(|t| t.get("sensor")?.get("preset")?.as_str().map(str::to_owned))
        .unwrap_or_default();
    let mut frames = Vec::with_capacity(labels.len());
    let (mut width, mut height) = (0u32, 0u32);
    for (f, fl) in labels.iter().enumerate() {
        let mask_path = dir.join("masks").join(format!("{f:06}.png"));
        let mask = image::ImageReader::open(&mask_path)
            .map_err(|e| io(&mask_path, e))?
            .decode()
            .map_err(|e| MergeError::Corrupt(format!("{}: not a mask a recording writes: {e}", mask_path.display())))?
            .into_luma8();
        (width, height) = mask.dimensions();
        let binary: Vec<u8> = mask.as_raw().iter().map(|&v| if v > 0 { 255 } else { 0 }).collect();
        let stem = format!("{}_{f:06}", sequence_name(k));
        put(stage, &format!("sirst/masks/{stem}.png"), &gray8_png(&binary, width, height)?)?;
        let (w, h) = (u64::from(width), u64::from(height));
        // each target's pixels as column-major indices, sorted
        let mut pixels: BTreeMap<u8, Vec<u64>> = BTreeMap::new();
        for (y, row) in mask.as_raw().chunks_exact(width as usize).enumerate() {
            for (x, &v) in row.iter().enumerate() {
                if v > 0 {
                    pixels.entry(v).or_default().push(x as u64 * h + y as u64);
                }
            }
        }
        for p in pixels.values_mut() {
            p.sort_unstable();
        }
        let mut annotations = Vec::new();
        for t in fl.targets.iter().filter(|t| t.in_frame) {
            let [x0, y0, x1, y1] = t.bbox_px;
            let bbox = [milli(x0), milli(y0), milli(x1 - x0), milli(y1 - y0)];
            if bbox[2] <= 0.0 || bbox[3] <= 0.0 {
                continue;
            }
            let class = class_of(&t.name).ok_or_else(|| {
                MergeError::Corrupt(format!(
                    "{}: frame {f}: target `{}` is not named after a class ({})",
                    labels_path.display(),
                    t.name,
                    TargetClass::ALL.map(|c| c.name).join(", ")
                ))
            })?;
            let own = u8::try_from(t.id).ok().and_then(|id| pixels.get(&id));
            let area = own.map_or(bbox[2] * bbox[3], |p| p.len() as f64);
            annotations.push(Annotation {
                track_id: t.id,
                class,
                bbox,
                area,
                rle: rle(own.map_or(&[][..], |p| p), w * h),
                snr: t.snr,
                scr: t.scr,
                range_m: t.range_m,
                altitude_m: t.altitude_m,
                peak_dn: t.peak_dn,
                local_contrast: t.local_contrast,
                apparent_temp_k: t.apparent_temp_k,
                detectable: t.detectable,
            });
        }
        frames.push(FrameEntry { frame: fl.frame, t_s: fl.t_s, annotations });
    }
    Ok(SequenceEntry { k, set, width, height, sensor, frames })
}

/// The staging directory's files: what to write, and what to link.
#[derive(Default)]
struct Staged {
    /// Relative path → bytes.
    files: Vec<(String, Vec<u8>)>,
    /// Relative path in the exports → relative path of a sequence's file (a hard link, or a copy).
    links: Vec<(String, String)>,
}

/// The per-frame exports of one sequence: YOLO labels, the MOT folder, and the links to its frames.
fn stage_sequence(out: &Path, spec: &DatasetSpec, s: &SequenceEntry) -> Result<Staged, MergeError> {
    let mut st = Staged::default();
    let name = sequence_name(s.k);
    let set = s.set.name();
    let (w, h) = (f64::from(s.width), f64::from(s.height));
    for fe in &s.frames {
        let frame_file = format!("sequences/{name}/frames/{:06}.png", fe.frame);
        let stem = format!("{name}_{:06}", fe.frame);
        // YOLO: class x_center y_center width height, normalized
        let mut yolo = String::new();
        for a in &fe.annotations {
            let [x, y, bw, bh] = a.bbox;
            let _ = writeln!(
                yolo,
                "{} {:.6} {:.6} {:.6} {:.6}",
                a.class,
                (x + 0.5 * bw) / w,
                (y + 0.5 * bh) / h,
                bw / w,
                bh / h
            );
        }
        st.files.push((format!("yolo/labels/{set}/{stem}.txt"), yolo.into_bytes()));
        st.links.push((format!("yolo/images/{set}/{stem}.png"), frame_file.clone()));
        // SIRST: the binary mask (written while reading) beside the image
        st.links.push((format!("sirst/images/{stem}.png"), frame_file.clone()));
        // MOTChallenge: img1/ counts from 1
        st.links.push((format!("mot/{set}/{name}/img1/{:06}.png", fe.frame + 1), frame_file));
    }
    let gt = sequence_dir(out, s.k).join("gt_mot.txt");
    let gt_bytes = std::fs::read(&gt).map_err(|e| io(&gt, e))?;
    st.files.push((format!("mot/{set}/{name}/gt/gt.txt"), gt_bytes));
    let seqinfo = format!(
        "[Sequence]\nname={name}\nimDir=img1\nframeRate={}\nseqLength={}\nimWidth={}\nimHeight={}\nimExt=.png\n",
        spec.frame_rate_hz,
        s.frames.len(),
        s.width,
        s.height
    );
    st.files.push((format!("mot/{set}/{name}/seqinfo.ini"), seqinfo.into_bytes()));
    Ok(st)
}

/// An 8-bit grayscale PNG.
fn gray8_png(pixels: &[u8], width: u32, height: u32) -> Result<Vec<u8>, MergeError> {
    let mut bytes = Vec::new();
    crate::imaging::frame::write_gray8_png(pixels, width as usize, height as usize, &mut bytes)
        .map_err(|e| MergeError::Io(format!("encoding a mask: {e}")))?;
    Ok(bytes)
}

/// The COCO file of the sequences `seqs` (one set, or all).
fn coco(spec: &DatasetSpec, seqs: &[&SequenceEntry], set: Option<Set>) -> Value {
    let mut images = Vec::new();
    let mut annotations = Vec::new();
    // ids are the same in every file: image k·frames + f + 1, annotations numbered over the whole dataset
    let mut ann_id = 0u64;
    for s in seqs {
        for fe in &s.frames {
            let image_id = s.k * spec.frames + fe.frame + 1;
            let keep = set.is_none_or(|x| x == s.set);
            if keep {
                images.push(json!({
                    "id": image_id,
                    "file_name": format!("sequences/{}/frames/{:06}.png", sequence_name(s.k), fe.frame),
                    "width": s.width,
                    "height": s.height,
                    "sequence": sequence_name(s.k),
                    "frame": fe.frame,
                    "t_s": fe.t_s,
                    "split": s.set.name(),
                    "sensor": s.sensor,
                }));
            }
            for a in &fe.annotations {
                ann_id += 1;
                if !keep {
                    continue;
                }
                annotations.push(json!({
                    "id": ann_id,
                    "image_id": image_id,
                    "category_id": a.class + 1,
                    "bbox": a.bbox,
                    "area": a.area,
                    "segmentation": { "size": [s.height, s.width], "counts": a.rle },
                    "iscrowd": 0,
                    "track_id": a.track_id,
                    "attributes": {
                        "class": TargetClass::ALL[a.class].name,
                        "snr": a.snr,
                        "scr": a.scr,
                        "range_m": a.range_m,
                        "altitude_m": a.altitude_m,
                        "peak_dn": a.peak_dn,
                        "local_contrast": a.local_contrast,
                        "apparent_temp_k": a.apparent_temp_k,
                        "detectable": a.detectable,
                        "sequence": sequence_name(s.k),
                        "frame": fe.frame,
                    },
                }));
            }
        }
    }
    let categories: Vec<Value> = TargetClass::ALL
        .iter()
        .enumerate()
        .map(|(i, c)| json!({ "id": i + 1, "name": c.name, "supercategory": "airborne" }))
        .collect();
    json!({
        "info": {
            "description": format!("irsim dataset `{}` (seed {}), {}", spec.name, spec.seed, set.map_or("all sets", Set::name)),
            "version": env!("CARGO_PKG_VERSION"),
            "contributor": "irsim",
        },
        "licenses": [],
        "images": images,
        "annotations": annotations,
        "categories": categories,
    })
}

/// Every regular file under `root` (relative paths with `/`, sorted), skipping hidden entries and `skip`.
fn walk(root: &Path, skip: &[&str]) -> Result<Vec<String>, MergeError> {
    let mut out = Vec::new();
    let mut stack = vec![PathBuf::new()];
    while let Some(rel) = stack.pop() {
        let dir = root.join(&rel);
        for e in std::fs::read_dir(&dir).map_err(|e| io(&dir, e))? {
            let e = e.map_err(|e| io(&dir, e))?;
            let name = e.file_name().to_string_lossy().into_owned();
            let r = if rel.as_os_str().is_empty() { name.clone() } else { format!("{}/{name}", rel.display()) };
            if name.starts_with('.') || skip.contains(&r.as_str()) {
                continue;
            }
            let ft = e.file_type().map_err(|e| io(&dir, e))?;
            if ft.is_dir() {
                stack.push(PathBuf::from(&r));
            } else if ft.is_file() {
                out.push(r);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// SHA-256 of a file, hex.
fn sha256_file(path: &Path) -> Result<String, MergeError> {
    let mut f = std::fs::File::open(path).map_err(|e| io(path, e))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf).map_err(|e| io(path, e))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(hex(&h.finalize()))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::with_capacity(bytes.len() * 2), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// The sha256sum lines of every file under `root` but the manifest and the checksums themselves; a file hard
/// linked several times is read once.
fn checksums(root: &Path) -> Result<(String, u64), MergeError> {
    let files = walk(root, &["manifest.json", "checksums.sha256", "shards"])?;
    let key = |p: &Path| -> Option<(u64, u64)> {
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt as _;
            std::fs::metadata(p).ok().filter(|m| m.nlink() > 1).map(|m| (m.dev(), m.ino()))
        }
        #[cfg(not(unix))]
        {
            let _ = p;
            None
        }
    };
    let keys: Vec<Option<(u64, u64)>> = files.iter().map(|f| key(&root.join(f))).collect();
    // hash each distinct file once: the first path of each inode, and every unlinked file
    let mut first: BTreeMap<(u64, u64), usize> = BTreeMap::new();
    let mut todo = Vec::new();
    for (i, k) in keys.iter().enumerate() {
        match k {
            Some(k) if first.contains_key(k) => {}
            Some(k) => {
                first.insert(*k, i);
                todo.push(i);
            }
            None => todo.push(i),
        }
    }
    let hashed: Vec<(usize, String)> =
        todo.par_iter().map(|&i| sha256_file(&root.join(&files[i])).map(|h| (i, h))).collect::<Result<_, _>>()?;
    let mut hashes = vec![String::new(); files.len()];
    for (i, h) in hashed {
        hashes[i] = h;
    }
    for (i, k) in keys.iter().enumerate() {
        if let Some(k) = k
            && hashes[i].is_empty()
        {
            hashes[i] = hashes[first[k]].clone();
        }
    }
    let mut text = String::new();
    for (f, h) in files.iter().zip(&hashes) {
        let _ = writeln!(text, "{h}  {f}");
    }
    Ok((text, files.len() as u64))
}

/// Writes `bytes` to `root/rel`, making its folders.
fn put(root: &Path, rel: &str, bytes: &[u8]) -> Result<(), MergeError> {
    let path = root.join(rel);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| io(parent, e))?;
    }
    std::fs::write(&path, bytes).map_err(|e| io(&path, e))
}

/// Links `root/rel` to `out/source` (a hard link; a copy where the file system has none).
fn link(out: &Path, root: &Path, rel: &str, source: &str) -> Result<(), MergeError> {
    let path = root.join(rel);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| io(parent, e))?;
    }
    let src = out.join(source);
    if std::fs::hard_link(&src, &path).is_err() {
        std::fs::copy(&src, &path).map_err(|e| io(&path, e))?;
    }
    Ok(())
}

/// What a shard's record says, for the report of what is missing.
fn shard_records(out: &Path) -> Vec<(u64, u64, String)> {
    let mut records = Vec::new();
    if let Ok(entries) = std::fs::read_dir(out.join("shards")) {
        for e in entries.flatten() {
            if let Some(v) = std::fs::read_to_string(e.path()).ok().and_then(|t| serde_json::from_str::<Value>(&t).ok())
                && let (Some(i), Some(n), Some(s)) = (v["shard"].as_u64(), v["of"].as_u64(), v["status"].as_str())
            {
                records.push((i, n, s.to_owned()));
            }
        }
    }
    records.sort();
    records
}

/// Says which sequences are missing and which shards to run (again).
fn missing_report(out: &Path, spec: &DatasetSpec, missing: &[u64]) -> String {
    let names: Vec<String> = missing.iter().take(8).map(|&k| sequence_name(k)).collect();
    let more = if missing.len() > 8 { format!(" and {} more", missing.len() - 8) } else { String::new() };
    let mut msg = format!(
        "{}: {} of {} sequences are not complete ({}{more}); nothing was merged",
        out.display(),
        missing.len(),
        spec.sequences,
        names.join(", ")
    );
    let records = shard_records(out);
    // the shard count most records name
    let mut counts: BTreeMap<u64, usize> = BTreeMap::new();
    for r in &records {
        *counts.entry(r.1).or_default() += 1;
    }
    if let Some((&n, _)) = counts.iter().max_by_key(|(n, c)| (**c, std::cmp::Reverse(**n))) {
        let mut shards: Vec<u64> = missing.iter().map(|k| k % n + 1).collect();
        shards.sort_unstable();
        shards.dedup();
        for i in shards {
            let state = records
                .iter()
                .find(|r| r.0 == i && r.1 == n)
                .map_or("has not reported (not run, still running, or stopped hard)".to_owned(), |r| {
                    format!("reported `{}`", r.2)
                });
            let _ = write!(
                msg,
                "\n  shard {i}/{n} {state}: run `irsim dataset SPEC --out {} --shard {i}/{n}`",
                out.display()
            );
        }
    } else {
        let _ =
            write!(msg, "\n  no shard has reported: run `irsim dataset SPEC --out {}` (or its shards)", out.display());
    }
    msg
}

/// Builds the dataset-level files of the dataset in `out` from its complete sequences.
///
/// # Errors
/// [`MergeError::Incomplete`] when a sequence is missing or unfinished (saying which shards to run);
/// [`MergeError::Corrupt`] for a sequence's files that a recording did not write; [`MergeError::Io`].
pub fn merge(out: &Path, spec: &DatasetSpec, progress: &dyn Fn(&str)) -> Result<MergeSummary, MergeError> {
    let missing: Vec<u64> = (0..spec.sequences).filter(|&k| !complete(&sequence_dir(out, k))).collect();
    if !missing.is_empty() {
        return Err(MergeError::Incomplete(missing_report(out, spec, &missing)));
    }
    let sets = spec.splits();
    let stage = out.join(".merge.partial");
    if stage.exists() {
        std::fs::remove_dir_all(&stage).map_err(|e| io(&stage, e))?;
    }
    std::fs::create_dir_all(&stage).map_err(|e| io(&stage, e))?;
    let merged = merge_staged(out, spec, &stage, &sets, progress);
    if merged.is_err() {
        // a failed merge leaves the exports of the last good one, and nothing half made
        let _ = std::fs::remove_dir_all(&stage);
    }
    merged
}

/// The merge's work after the check for missing sequences: everything built in `stage`, then moved into place.
fn merge_staged(
    out: &Path,
    spec: &DatasetSpec,
    stage: &Path,
    sets: &[Set],
    progress: &dyn Fn(&str),
) -> Result<MergeSummary, MergeError> {
    progress("reading the sequences' labels and masks; the SIRST masks");
    let seqs: Vec<SequenceEntry> = (0..spec.sequences)
        .into_par_iter()
        .map(|k| read_sequence(out, stage, spec, k, sets[k as usize]))
        .collect::<Result<_, _>>()?;
    progress("writing the YOLO and MOTChallenge exports");
    seqs.par_iter().try_for_each(|s| -> Result<(), MergeError> {
        let st = stage_sequence(out, spec, s)?;
        for (rel, bytes) in &st.files {
            put(stage, rel, bytes)?;
        }
        for (rel, source) in &st.links {
            link(out, stage, rel, source)?;
        }
        Ok(())
    })?;
    // every set's folders exist, empty or not, as the tools expect them
    for set in Set::ALL {
        for d in [format!("yolo/images/{}", set.name()), format!("yolo/labels/{}", set.name())] {
            std::fs::create_dir_all(stage.join(&d)).map_err(|e| io(&stage.join(&d), e))?;
        }
    }
    progress("writing COCO, the split and the card");
    let all: Vec<&SequenceEntry> = seqs.iter().collect();
    let pretty = |v: &Value| serde_json::to_vec(v).expect("JSON serializes");
    put(stage, "coco/all.json", &pretty(&coco(spec, &all, None)))?;
    for set in Set::ALL {
        put(stage, &format!("coco/{}.json", set.name()), &pretty(&coco(spec, &all, Some(set))))?;
        let mut list = String::new();
        let mut stems = String::new();
        for s in seqs.iter().filter(|s| s.set == set) {
            let _ = writeln!(list, "{}", sequence_name(s.k));
            for fe in &s.frames {
                let _ = writeln!(stems, "{}_{:06}", sequence_name(s.k), fe.frame);
            }
        }
        put(stage, &format!("splits/{}.txt", set.name()), list.as_bytes())?;
        put(stage, &format!("sirst/{}.txt", set.name()), stems.as_bytes())?;
    }
    put(stage, "yolo/data.yaml", yolo_yaml(spec).as_bytes())?;
    let stats = super::card::Stats::gather(seqs.iter().map(|s| {
        (
            s.set,
            s.sensor.as_str(),
            s.frames
                .iter()
                .flat_map(|f| {
                    let middle = f.frame == spec.frames / 2;
                    f.annotations.iter().map(move |a| super::card::Sample {
                        class: a.class,
                        snr: a.snr,
                        size_px: a.area,
                        range_m: a.range_m,
                        altitude_m: a.altitude_m,
                        detectable: a.detectable,
                        middle,
                    })
                })
                .collect::<Vec<_>>(),
            s.frames.len() as u64,
        )
    }));
    super::card::write(stage, spec, &stats).map_err(MergeError::Io)?;
    // into place: each export replaces the one of an earlier merge
    let entries: Vec<String> = std::fs::read_dir(stage)
        .map_err(|e| io(stage, e))?
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect();
    for name in entries {
        let dest = out.join(&name);
        if dest.is_dir() {
            std::fs::remove_dir_all(&dest).map_err(|e| io(&dest, e))?;
        } else if dest.exists() {
            std::fs::remove_file(&dest).map_err(|e| io(&dest, e))?;
        }
        std::fs::rename(stage.join(&name), &dest).map_err(|e| io(&dest, e))?;
    }
    std::fs::remove_dir_all(stage).map_err(|e| io(stage, e))?;
    progress("checksums of every file");
    let (sums, files) = checksums(out)?;
    crate::record::write_atomic(&out.join("checksums.sha256"), sums.as_bytes())
        .map_err(|e| MergeError::Io(e.to_string()))?;
    let spec_text = std::fs::read(out.join("spec.toml")).map_err(|e| io(&out.join("spec.toml"), e))?;
    let annotations: u64 = seqs.iter().flat_map(|s| &s.frames).map(|f| f.annotations.len() as u64).sum();
    let by_set: serde_json::Map<String, Value> = Set::ALL
        .iter()
        .map(|&set| {
            let n = seqs.iter().filter(|s| s.set == set).count() as u64;
            (set.name().to_owned(), json!({ "sequences": n, "frames": n * spec.frames }))
        })
        .collect();
    let manifest = json!({
        "program": "irsim",
        "version": env!("CARGO_PKG_VERSION"),
        "dataset": spec.name,
        "seed": spec.seed,
        "spec": { "file": "spec.toml", "sha256": hex(&Sha256::digest(&spec_text)) },
        "sequences": spec.sequences,
        "frames_per_sequence": spec.frames,
        "frames": spec.sequences * spec.frames,
        "annotations": annotations,
        "splits": by_set,
        "exports": {
            "coco": "coco/{all,train,val,test}.json",
            "yolo": "yolo/data.yaml",
            "sirst": "sirst/{images,masks}/, sirst/{train,val,test}.txt",
            "mot": "mot/{train,val,test}/seq_NNNNNN/{img1,gt/gt.txt,seqinfo.ini}",
            "card": "README.md, card/*.png",
            "splits": "splits/{train,val,test}.txt",
        },
        "checksums": { "file": "checksums.sha256", "sha256": hex(&Sha256::digest(sums.as_bytes())), "files": files },
    });
    let text = serde_json::to_string_pretty(&manifest).expect("manifest serializes") + "\n";
    crate::record::write_atomic(&out.join("manifest.json"), text.as_bytes())
        .map_err(|e| MergeError::Io(e.to_string()))?;
    // the shards' records served their purpose: the dataset is whole, and the same whatever ran it
    let shards = out.join("shards");
    if shards.exists() {
        std::fs::remove_dir_all(&shards).map_err(|e| io(&shards, e))?;
    }
    Ok(MergeSummary { frames: spec.sequences * spec.frames, annotations, files })
}

/// Ultralytics' dataset file: the image folders relative to it, the class names by index.
fn yolo_yaml(spec: &DatasetSpec) -> String {
    let mut y = format!(
        "# irsim dataset `{}` (seed {}): YOLO detection labels.\n# labels/<set>/<image>.txt beside images/<set>/<image>.png (16-bit grayscale, the frames' own files),\n# one line per target in frame: class x_center y_center width height, each divided by the image's size.\n# Folders are relative to this file.\ntrain: images/train\nval: images/val\ntest: images/test\nnc: {}\nnames:\n",
        spec.name,
        spec.seed,
        TargetClass::ALL.len()
    );
    for (i, c) in TargetClass::ALL.iter().enumerate() {
        let _ = writeln!(y, "  {i}: {}", c.name);
    }
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rle_counts_runs_of_background_and_mask_column_major() {
        // a 3×2 image (w 3, h 2): pixels (x 1, y 0), (x 1, y 1), (x 2, y 1) → indices 2, 3, 5 of 6
        assert_eq!(rle(&[2, 3, 5], 6), vec![2, 2, 1, 1, 0]);
        assert_eq!(rle(&[], 6), vec![6]);
        assert_eq!(rle(&[0], 1), vec![0, 1, 0]);
        let counts = rle(&[0, 1, 7, 9, 10], 12);
        assert_eq!(counts.iter().sum::<u64>(), 12);
    }

    #[test]
    fn classes_come_from_the_drawn_names() {
        assert_eq!(class_of("small_multirotor_0"), Some(0));
        assert_eq!(class_of("bird_12"), Some(5));
        assert_eq!(class_of("fixed_wing_uav_3"), Some(1));
        assert_eq!(class_of("jet_1"), None);
    }
}
