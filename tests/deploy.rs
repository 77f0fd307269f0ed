//! The cluster files: the Kubernetes manifest validates against the Kubernetes schema (kubernetes-validate, in
//! strict mode: no unknown fields) and carries a spec irsim accepts; the Slurm scripts parse and refuse to run
//! outside an array. The Slurm cluster test itself is tests/cluster/slurm.sh (`CI_SLURM=1 bash .ci/run`).

mod common;

use std::process::Command;

use common::{irsim, python_tool, root, temp_dir};

#[test]
fn the_kubernetes_manifest_is_valid_and_its_spec_is_one_irsim_accepts() {
    let manifest = root().join("deploy/kubernetes/irsim-dataset.yaml");
    let text = std::fs::read_to_string(&manifest).unwrap();
    // the ConfigMap's spec: the block under `spec.toml: |`, 4 spaces in
    let start = text.find("spec.toml: |\n").expect("the ConfigMap holds spec.toml") + "spec.toml: |\n".len();
    let spec: String = text[start..]
        .lines()
        .take_while(|l| l.starts_with("    ") || l.is_empty())
        .map(|l| format!("{}\n", l.get(4..).unwrap_or("")))
        .collect();
    let dir = temp_dir("deploy_spec");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("spec.toml");
    std::fs::write(&path, &spec).unwrap();
    // a spec that loads: recording it with a bad shard is refused for the shard, not the spec
    let (code, _, err) =
        irsim(&["dataset", path.to_str().unwrap(), "--out", dir.join("out").to_str().unwrap(), "--shard", "0/4"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--shard"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
    // the shard count is said twice (completions and IRSIM_SHARDS): the same number
    let completions = text.lines().find_map(|l| l.trim().strip_prefix("completions: ")).unwrap();
    let completions = completions.split_whitespace().next().unwrap();
    assert!(text.contains(&format!("value: \"{completions}\"  # EDIT: the same N as completions")), "{completions}");
    assert!(text.contains("JOB_COMPLETION_INDEX + 1"));

    if !python_tool(&["kubernetes-validate", "--version"], "kubernetes-validate") {
        return;
    }
    for version in ["1.33.0", "1.37.0"] {
        let out = Command::new("kubernetes-validate")
            .args(["--strict", "--no-warn", "-k", version])
            .arg(&manifest)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{version}: {said}");
        assert_eq!(said.matches("passed for resource").count(), 7, "{said}");
    }
}

#[test]
fn the_slurm_scripts_parse_and_refuse_to_run_outside_an_array() {
    for script in ["deploy/slurm/irsim-dataset.sbatch", "deploy/slurm/submit.sh", "tests/cluster/slurm.sh"] {
        let out = Command::new("bash").arg("-n").arg(root().join(script)).output().unwrap();
        assert!(out.status.success(), "{script}: {}", String::from_utf8_lossy(&out.stderr));
    }
    let sbatch = root().join("deploy/slurm/irsim-dataset.sbatch");
    let run = |args: &[&str], env: &[(&str, &str)]| {
        let mut c = Command::new("bash");
        c.arg(&sbatch).args(args).env("IRSIM", env!("CARGO_BIN_EXE_irsim"));
        for k in ["SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_MIN", "SLURM_ARRAY_TASK_MAX", "SLURM_ARRAY_TASK_COUNT"] {
            c.env_remove(k);
        }
        c.envs(env.iter().copied());
        let out = c.output().unwrap();
        (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (code, err) = run(&[], &[]);
    assert_eq!(code, 2, "{err}");
    let (code, err) = run(&["shard", "spec.toml", "out"], &[]);
    assert_ne!(code, 0, "{err}");
    assert!(err.contains("sbatch --array=1-N"), "{err}");
    // an array that does not run 1-N would leave shards out
    let (code, err) = run(
        &["shard", "spec.toml", "out"],
        &[
            ("SLURM_ARRAY_TASK_ID", "2"),
            ("SLURM_ARRAY_TASK_MIN", "0"),
            ("SLURM_ARRAY_TASK_MAX", "3"),
            ("SLURM_ARRAY_TASK_COUNT", "4"),
        ],
    );
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("1-N"), "{err}");
    // task 2 of 1-2 records shard 2/2 of the spec given
    let dir = temp_dir("deploy_sbatch");
    std::fs::create_dir_all(&dir).unwrap();
    let spec = dir.join("spec.toml");
    std::fs::write(
        &spec,
        "name = \"s\"\nseed = 1\nsequences = 2\nframes = 1\nsensors = [\"paper_lwir_256\"]\ntargets_per_sequence = [1, 1]\nclasses = [\"bird\"]\ntrajectories = [\"straight\"]\nrange_m = [300, 600]\n",
    )
    .unwrap();
    let out = dir.join("out");
    let (code, err) = run(
        &["shard", spec.to_str().unwrap(), out.to_str().unwrap()],
        &[
            ("SLURM_ARRAY_TASK_ID", "2"),
            ("SLURM_ARRAY_TASK_MIN", "1"),
            ("SLURM_ARRAY_TASK_MAX", "2"),
            ("SLURM_ARRAY_TASK_COUNT", "2"),
        ],
    );
    assert_eq!(code, 0, "{err}");
    assert!(out.join("sequences/seq_000001/manifest.json").is_file() && !out.join("sequences/seq_000000").exists());
    assert!(out.join("shards/shard-2-of-2.json").is_file());
    let (code, err) = run(&["merge", out.to_str().unwrap()], &[]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("shard 1/2"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
