//! `irsim dataset` as a user runs it: sequences drawn from a spec, recorded whole, the same bytes for any shard
//! count, resumed after an interruption; bad specs refused with their place.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{irsim, python_tool, root, temp_dir};

/// Four short sequences with the paper's 256×256 camera.
const SPEC: &str = r#"
name = "tiny"
seed = 11
sequences = 4
frames = 3
quality = "draft"
sensors = ["paper_lwir_256"]
targets_per_sequence = [1, 2]
classes = ["small_multirotor", "fixed_wing_uav", "bird"]
trajectories = ["straight", "crossing", "approach", "coordinated_turn", "weave"]
range_m = [300, 1500]

[sky]
kinds = ["clear", "cumulus", "none"]
"#;

/// Every file under `dir` (relative path → bytes).
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.strip_prefix(dir).unwrap().display().to_string(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

fn run(spec: &Path, out: &Path, shard: &str) -> (i32, String) {
    let (code, _, err) =
        irsim(&["dataset", spec.to_str().unwrap(), "--out", out.to_str().unwrap(), "--shard", shard, "--quiet"]);
    (code, err)
}

#[test]
fn sequences_are_the_same_bytes_for_any_shard_count_and_a_rerun_skips_them() {
    let dir = temp_dir("dataset_shards");
    std::fs::create_dir_all(&dir).unwrap();
    let spec = dir.join("tiny.toml");
    std::fs::write(&spec, SPEC).unwrap();
    let mut by_count = Vec::new();
    for count in 1..=3 {
        let out = dir.join(format!("out{count}"));
        // shards in reverse order: a sequence does not depend on what ran before it
        for index in (1..=count).rev() {
            let (code, err) = run(&spec, &out, &format!("{index}/{count}"));
            assert_eq!(code, 0, "{err}");
            if count > 1 {
                assert!(err.contains("irsim dataset merge"), "{err}");
            }
        }
        if count > 1 {
            let (code, _, err) = irsim(&["dataset", "merge", out.to_str().unwrap(), "--quiet"]);
            assert_eq!(code, 0, "{err}");
        }
        // the exports, the card and the checksums, and no shard records left to tell the runs apart
        for f in [
            "README.md",
            "manifest.json",
            "checksums.sha256",
            "coco/all.json",
            "coco/train.json",
            "yolo/data.yaml",
            "splits/test.txt",
            "card/snr.png",
            "sirst/train.txt",
        ] {
            assert!(out.join(f).is_file(), "{f} missing after {count} shards");
        }
        assert!(!out.join("shards").exists());
        let all = files(&out);
        let all_seq = files(&out.join("sequences"));
        assert!(all.keys().any(|k| k.ends_with("scenario.toml")), "{:?}", all.keys());
        for k in 0..4 {
            let seq = format!("seq_{k:06}");
            for f in [
                "scenario.toml",
                "labels.jsonl",
                "gt_mot.txt",
                "manifest.json",
                "frames/000002.png",
                "masks/000000.png",
            ] {
                assert!(all_seq.contains_key(&format!("{seq}/{f}")), "{seq}/{f} missing");
            }
        }
        assert!(!all.keys().any(|k| k.contains(".partial") || k.ends_with(".tmp")), "{:?}", all.keys());
        assert!(all_seq.keys().all(|k| all.contains_key(&format!("sequences/{k}"))));
        by_count.push(all);
    }
    for (i, other) in by_count.iter().enumerate().skip(1) {
        let differ: Vec<&String> = by_count[0].keys().filter(|k| by_count[0].get(*k) != other.get(*k)).collect();
        assert!(by_count[0] == *other, "1 shard and {} shards differ: {differ:?}", i + 1);
    }

    // the formats' own tools read the exports (skipped, saying so, where they are not installed)
    python_check(&dir.join("out1"));

    // every drawn scenario is a scenario `irsim validate` accepts, and re-records to the same frames
    let seq = dir.join("out1/sequences/seq_000001");
    let (code, _, err) = irsim(&["validate", seq.join("scenario.toml").to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    records_again(&seq, &dir.join("again"), "000002.png");

    // a rerun finds everything complete; a left-over partial sequence (a pre-empted run) is made again
    let out = dir.join("out1");
    let (code, err) = run(&spec, &out, "1/1");
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("0 sequences recorded, 4 already complete"), "{err}");
    std::fs::rename(out.join("sequences/seq_000002"), out.join("sequences/.seq_000002.partial")).unwrap();
    std::fs::remove_file(out.join("sequences/.seq_000002.partial/manifest.json")).unwrap();
    let (code, err) = run(&spec, &out, "1/1");
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("1 sequences recorded, 3 already complete"), "{err}");
    assert!(files(&out) == by_count[0]);

    // another spec in the same directory is refused, nothing touched
    let other = dir.join("other.toml");
    std::fs::write(&other, SPEC.replace("seed = 11", "seed = 12")).unwrap();
    let (code, err) = run(&other, &out, "1/1");
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("another spec"), "{err}");
    assert!(files(&out) == by_count[0]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// [`SPEC`] with targets placed by SNR, a camera flying straight or turning, and the shipped sky images among
/// the skies (`FOLDER` is replaced by their folder).
const SPEC_MOVING: &str = r#"
name = "moving"
seed = 4
sequences = 4
frames = 4
quality = "draft"
sensors = ["paper_lwir_256"]
targets_per_sequence = [1, 2]
classes = ["small_multirotor", "fixed_wing_uav", "light_aircraft"]
trajectories = ["straight", "crossing", "coordinated_turn", "weave"]
snr = [4, 40]
range_m = [100, 20000]

[observer]
speed_m_s = [10, 50]
turn_rate_deg_s = [-8, 8]

[sky]
kinds = ["image", "image", "cumulus"]

[sky.images]
folder = "FOLDER"
calibration = { mode = "temperature", value_range = [0, 65535], temp_range_k = [205, 265] }
roll_deg = [-20, 20]
"#;

#[test]
fn snr_solves_moving_cameras_and_user_skies_are_the_same_bytes_for_any_shard_count() {
    let dir = temp_dir("dataset_moving");
    let skies = dir.join("my skies");
    std::fs::create_dir_all(&skies).unwrap();
    for name in ["clear.png", "cumulus.png"] {
        std::fs::copy(root().join("assets/skies").join(name), skies.join(name)).unwrap();
    }
    // not an image: left out
    std::fs::write(skies.join("notes.txt"), "from the roof, 2026-06-01").unwrap();
    let spec = dir.join("moving.toml");
    std::fs::write(&spec, SPEC_MOVING.replace("FOLDER", "my skies")).unwrap();
    let mut trees = Vec::new();
    for count in [1, 2] {
        let out = dir.join(format!("out{count}"));
        for index in 1..=count {
            let (code, err) = run(&spec, &out, &format!("{index}/{count}"));
            assert_eq!(code, 0, "{err}");
        }
        if count > 1 {
            let (code, _, err) = irsim(&["dataset", "merge", out.to_str().unwrap(), "--quiet"]);
            assert_eq!(code, 0, "{err}");
        }
        trees.push(files(&out));
    }
    let differ: Vec<&String> = trees[0].keys().filter(|k| trees[0].get(*k) != trees[1].get(*k)).collect();
    assert!(trees[0] == trees[1], "1 and 2 shards differ: {differ:?}");
    let out = dir.join("out1");
    // the images are in the dataset, checksummed, and named by the scenarios that drew them
    assert_eq!(
        std::fs::read(out.join("skies/cumulus.png")).unwrap(),
        std::fs::read(skies.join("cumulus.png")).unwrap()
    );
    assert!(!out.join("skies/notes.txt").exists());
    let sums = std::fs::read_to_string(out.join("checksums.sha256")).unwrap();
    assert!(sums.contains("  skies/clear.png\n"), "{sums}");
    let scenarios: Vec<String> = (0..4)
        .map(|k| std::fs::read_to_string(out.join(format!("sequences/seq_{k:06}/scenario.toml"))).unwrap())
        .collect();
    assert!(scenarios.iter().any(|s| s.contains("image = \"../../skies/")), "no sequence drew an image");
    assert!(scenarios.iter().all(|s| s.contains("mode = \"along_velocity\"")), "a camera stood still");
    // each target's SNR at the middle frame is the one asked, where range_m allowed it
    let mut solved = 0;
    for k in 0..4 {
        let seq = out.join(format!("sequences/seq_{k:06}"));
        let solve: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(seq.join("snr_solve.json")).unwrap()).unwrap();
        let middle = solve["frame"].as_u64().unwrap();
        let labels = std::fs::read_to_string(seq.join("labels.jsonl")).unwrap();
        let line: serde_json::Value = serde_json::from_str(labels.lines().nth(middle as usize).unwrap()).unwrap();
        for t in solve["targets"].as_array().unwrap() {
            let asked = t["asked"].as_f64().unwrap();
            assert!((4.0..=40.0).contains(&asked), "{t}");
            let id = t["id"].as_u64().unwrap();
            let label = line["targets"].as_array().unwrap().iter().find(|l| l["id"].as_u64() == Some(id)).unwrap();
            let snr = label["snr"].as_f64().unwrap();
            if t["limit"].is_null() {
                solved += 1;
                assert!((snr / asked - 1.0).abs() < 0.02, "sequence {k}: asked {asked}, the frame has {snr}");
            }
        }
    }
    assert!(solved >= 3, "{solved} targets solved");
    let card = std::fs::read_to_string(out.join("README.md")).unwrap();
    assert!(card.contains("| SNR at the middle frames | 4 – 40 (uniform);"), "{card}");
    python_check(&out);

    // a sequence that drew an image records again from its own folder
    let k = scenarios.iter().position(|s| s.contains("../../skies/")).unwrap();
    let seq = out.join(format!("sequences/seq_{k:06}"));
    records_again(&seq, &dir.join("again"), "000003.png");

    // the same dataset with another image under the same name is refused, nothing touched
    std::fs::copy(skies.join("clear.png"), skies.join("cumulus.png")).unwrap();
    let (code, err) = run(&spec, &out, "1/1");
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("not the same image"), "{err}");
    assert!(files(&out) == trees[0]);
    // an image that does not decode is refused with the spec's place, before anything is written
    std::fs::write(skies.join("broken.png"), b"\x89PNG not really").unwrap();
    let (code, err) = run(&spec, &dir.join("out3"), "1/1");
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("moving.toml:22:") && err.contains("`sky.images.folder`") && err.contains("broken.png"),
        "{err}"
    );
    assert!(!dir.join("out3").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `irsim record` of the sequence `seq`'s own scenario into `again` gives its labels and its frame `frame` again.
fn records_again(seq: &Path, again: &Path, frame: &str) {
    let scenario = seq.join("scenario.toml");
    let (code, _, err) =
        irsim(&["record", scenario.to_str().unwrap(), "--out", again.to_str().unwrap(), "--masks", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(std::fs::read(again.join("labels.jsonl")).unwrap(), std::fs::read(seq.join("labels.jsonl")).unwrap());
    let frames = Path::new("frames").join(frame);
    assert_eq!(std::fs::read(again.join(&frames)).unwrap(), std::fs::read(seq.join(&frames)).unwrap(), "{frame}");
}

/// Runs tests/python/check_dataset.py on `dir` where python3 has pycocotools and motmetrics; with
/// `IRSIM_REQUIRE_PYTHON_TOOLS` set (CI), their absence is a failure.
fn python_check(dir: &Path) {
    if !python_tool(
        &["python3", "-c", "import pycocotools, motmetrics, numpy, PIL"],
        "python3 with pycocotools and motmetrics",
    ) {
        return;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_dataset.py");
    let out = std::process::Command::new("python3").arg(script).arg(dir).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("AP = 1.000") && text.contains("all checks passed"), "{text}");
}

#[test]
fn merge_names_the_shards_still_to_run_and_extra_frames_are_kept() {
    let dir = temp_dir("dataset_merge");
    std::fs::create_dir_all(&dir).unwrap();
    let spec = dir.join("tiny.toml");
    let text =
        SPEC.replace("sequences = 4", "sequences = 3") + "\n[outputs]\nclean_background = true\nnoise_free = true\n";
    std::fs::write(&spec, text).unwrap();
    let out = dir.join("out");
    let (code, err) = run(&spec, &out, "1/2");
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = irsim(&["dataset", "merge", out.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("1 of 3 sequences are not complete (seq_000001)"), "{err}");
    assert!(err.contains("shard 2/2 has not reported") && err.contains("--shard 2/2"), "{err}");
    assert!(!out.join("coco").exists() && out.join("shards").exists());
    let (code, _, err) = irsim(&["dataset", "merge", dir.join("nowhere").to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("spec.toml"), "{err}");
    let (code, err) = run(&spec, &out, "2/2");
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = irsim(&["dataset", "merge", out.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 0, "{err}");
    // the extra frames: the background without targets or noise, and the frame without noise
    let seq = out.join("sequences/seq_000000");
    let labels = std::fs::read_to_string(seq.join("labels.jsonl")).unwrap();
    let first: serde_json::Value = serde_json::from_str(labels.lines().next().unwrap()).unwrap();
    let read = |p: &Path| image::open(p).unwrap().into_luma16();
    let (frame, clean, quiet) = (
        read(&seq.join("frames/000000.png")),
        read(&seq.join("clean/000000.png")),
        read(&seq.join("noise_free/000000.png")),
    );
    assert_eq!(frame.dimensions(), clean.dimensions());
    assert!(seq.join("clean/000002.png").is_file() && seq.join("noise_free/000002.png").is_file());
    // noise: the frame differs from the noise-free one nearly everywhere
    let differ = frame.pixels().zip(quiet.pixels()).filter(|(a, b)| a != b).count();
    assert!(differ > frame.len() / 2, "{differ}");
    // the target: where the mask has it, the noise-free frame and the clean background differ
    let mask = image::open(seq.join("masks/000000.png")).unwrap().into_luma8();
    let on: Vec<(u32, u32)> = mask.enumerate_pixels().filter(|p| p.2[0] > 0).map(|p| (p.0, p.1)).collect();
    assert!(!on.is_empty(), "{first}");
    assert!(on.iter().any(|&(x, y)| quiet.get_pixel(x, y) != clean.get_pixel(x, y)), "{first}");
    // far from every target they agree within a level (the same sky, camera path and weather)
    let far = mask.enumerate_pixels().filter(|p| p.2[0] == 0).count();
    let same = clean
        .pixels()
        .zip(quiet.pixels())
        .zip(mask.pixels())
        .filter(|((a, b), m)| m[0] == 0 && a[0].abs_diff(b[0]) <= 1)
        .count();
    assert!(same as f64 > 0.95 * far as f64, "{same} of {far}");
    // a sequence's files broken after recording: refused with the place, the last merge's exports kept
    let coco = std::fs::read(out.join("coco/all.json")).unwrap();
    let labels_path = seq.join("labels.jsonl");
    let good = std::fs::read_to_string(&labels_path).unwrap();
    std::fs::write(&labels_path, good.replacen("{\"frame\":1,", "{\"frame\":nan,", 1)).unwrap();
    let (code, _, err) = irsim(&["dataset", "merge", out.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("seq_000000/labels.jsonl:2:"), "{err}");
    std::fs::write(&labels_path, &good).unwrap();
    let mask = seq.join("masks/000001.png");
    let good_mask = std::fs::read(&mask).unwrap();
    std::fs::write(&mask, b"not a png").unwrap();
    let (code, _, err) = irsim(&["dataset", "merge", out.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("masks/000001.png: not a mask a recording writes"), "{err}");
    assert!(!out.join(".merge.partial").exists());
    assert_eq!(std::fs::read(out.join("coco/all.json")).unwrap(), coco);
    std::fs::write(&mask, good_mask).unwrap();
    let sums = std::fs::read_to_string(out.join("checksums.sha256")).unwrap();
    assert!(sums.contains("  sequences/seq_000000/clean/000000.png\n"), "{sums}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_specs_are_refused_with_file_line_column_and_field() {
    let dir = temp_dir("dataset_bad");
    std::fs::create_dir_all(&dir).unwrap();
    for (change, field, line) in [
        (("range_m = [300, 1500]", "range_m = [1500, 300]"), "range_m", 11),
        (("range_m = [300, 1500]", "range_m = [nan, 300]"), "range_m", 11),
        (("range_m = [300, 1500]", "range_m = [300, 1500, 2000]"), "range_m", 11),
        (("range_m = [300, 1500]", "range_m = [300, inf]"), "range_m", 11),
        (("range_m = [300, 1500]", "range_m = \"far\""), "range_m", 11),
        (("targets_per_sequence = [1, 2]", "targets_per_sequence = [1]"), "targets_per_sequence", 8),
        (("frames = 3", "frames = 3\nframe_rate_hz = nan"), "frame_rate_hz", 6),
        (("sequences = 4", "sequences = -4"), "sequences", 4),
        (("targets_per_sequence = [1, 2]", "targets_per_sequence = [3, 2]"), "targets_per_sequence", 8),
        (("\"bird\"]", "\"dragon\"]"), "classes[2]", 9),
        (("quality = \"draft\"", "quality = \"best\""), "quality", 6),
        (("kinds = [", "kind = ["), "sky.kind", 14),
        (("range_m = [300, 1500]", "snr = [5, nan]"), "snr", 11),
        (("range_m = [300, 1500]", "snr = [50, 5]"), "snr", 11),
        (("range_m = [300, 1500]", "snr = [5, 50]\nsnr_draw = \"gaussian\""), "snr_draw", 12),
        (("range_m = [300, 1500]", "# no range"), "range_m", 1),
        (("\"none\"]", "\"none\", \"image\"]"), "sky.kinds", 14),
        (("[sky]", "[observer]\nheading_deg = [0, 90]\n[sky]"), "observer.heading_deg", 14),
        (("[sky]", "[observer]\nspeed_m_s = [10, 5]\n[sky]"), "observer.speed_m_s", 14),
        (
            ("[sky]", "[observer]\nspeed_m_s = [10, 50]\nturn_rate_deg_s = [0, 90]\n[sky]"),
            "observer.turn_rate_deg_s",
            15,
        ),
        (
            (
                "\"none\"]",
                "\"image\"]\n[sky.images]\nfolder = \"nowhere\"\ncalibration = { mode = \"temperature\", value_range = [0, 65535], temp_range_k = [205, 265] }",
            ),
            "sky.images.folder",
            16,
        ),
        (
            (
                "\"none\"]",
                "\"image\"]\n[sky.images]\nfolder = \".\"\ncalibration = { mode = \"temperature\", value_range = [1, 1], temp_range_k = [205, 265] }",
            ),
            "sky.images.calibration.value_range",
            17,
        ),
        (
            (
                "\"none\"]",
                "\"none\"]\n[sky.images]\nfolder = \".\"\ncalibration = { mode = \"kelvin\", scale_k = 0.01 }",
            ),
            "sky.images",
            15,
        ),
    ] {
        let spec = dir.join("bad.toml");
        let text = SPEC.replace(change.0, change.1);
        assert_ne!(text, SPEC, "{change:?}");
        std::fs::write(&spec, &text).unwrap();
        let (code, err) = run(&spec, &dir.join("out"), "1/1");
        assert_eq!(code, 2, "{change:?}: {err}");
        let place = format!("bad.toml:{line}:");
        assert!(err.contains(&place) && err.contains(&format!("`{field}`")), "{change:?}: {err}");
        assert!(!dir.join("out").exists(), "{change:?}: output made for a refused spec");
    }
    let spec = dir.join("good.toml");
    std::fs::write(&spec, SPEC).unwrap();
    for shard in ["0/2", "3/2", "1/0", "two"] {
        let (code, err) = run(&spec, &dir.join("out"), shard);
        assert_eq!(code, 2, "{shard}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
