//! Helpers shared by the tests that run the `irsim` binary.

use std::path::PathBuf;
use std::process::Command;

/// The crate's root.
#[allow(dead_code)] // not every test binary uses it
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the binary with `args`: exit code, stdout, stderr.
pub fn irsim(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_irsim")).args(args).output().expect("run irsim");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Whether the Python test tool `what` answers `command` (a program and its arguments). Where it does not, the
/// caller skips its check, saying so; with `IRSIM_REQUIRE_PYTHON_TOOLS` set (CI), its absence is a failure.
#[allow(dead_code)] // not every test binary uses it
pub fn python_tool(command: &[&str], what: &str) -> bool {
    let have = Command::new(command[0]).args(&command[1..]).output().is_ok_and(|o| o.status.success());
    if !have {
        let install = "pip install -r tests/python/requirements.txt";
        assert!(
            std::env::var_os("IRSIM_REQUIRE_PYTHON_TOOLS").is_none(),
            "{what} is missing, but IRSIM_REQUIRE_PYTHON_TOOLS is set ({install})"
        );
        eprintln!("skipped: this check needs {what} ({install})");
    }
    have
}

/// A fresh (absent) directory under the system's temporary directory, unique to this process.
pub fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("irsim-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A small valid scenario: 64×48 sensor looking north, two targets 3 and 4 km ahead crossing east and west.
#[allow(dead_code)] // not every test binary uses it
pub const SMALL_SCENARIO: &str = r#"
[run]
frame_rate_hz = 30
frames = 4
seed = 3

[sensor]
width = 64
height = 48
pixel_pitch_um = 17
focal_length_mm = 100
aperture_mm = 100
band_um = [8, 12]

[observer]
trajectory = { kind = "constant_velocity", position_m = [0, 0, 1000] }
pointing = { mode = "yaw_pitch_roll", yaw_deg = 0 }

[[targets]]
name = "a"
trajectory = { kind = "constant_velocity", position_m = [-20, 3000, 1005], velocity_m_s = [100, 0, 0] }
semi_axes_m = [4, 2, 1]

[[targets]]
name = "b"
trajectory = { kind = "constant_velocity", position_m = [10, 4000, 1010], velocity_m_s = [-80, 0, 0] }
semi_axes_m = [4, 2, 1]
brdf = { kd = 0.5, ks = 0.5, f0 = 0.05, roughness = 0.3 }
"#;
