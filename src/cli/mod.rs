//! The `irsim` command line: argument parsing, output, exit codes.
//!
//! Exit codes: 0 success, 1 a failure while running (I/O), 2 bad input (flags, values, files).

pub mod atmosphere;
pub mod calc;
pub mod dataset;
pub mod limits;
pub mod opencv;
pub mod report;
pub mod run;
pub mod steal;

use std::ffi::OsString;
use std::io::Write;

use clap::{Parser, Subcommand};
use thiserror::Error;

/// An error that ends the program.
#[derive(Debug, Error)]
pub enum CliError {
    /// Bad input: exit code 2.
    #[error("{0}")]
    Invalid(String),
    /// A failure while running: exit code 1.
    #[error("{0}")]
    Failed(String),
    /// Stopped by Ctrl-C (SIGINT), SIGTERM or SIGHUP after writing what was complete: exit code 130, as a
    /// shell reports a process killed by SIGINT.
    #[error("interrupted")]
    Interrupted,
}

impl CliError {
    /// The process exit code for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            CliError::Invalid(_) => 2,
            CliError::Failed(_) => 1,
            CliError::Interrupted => 130,
        }
    }
}

/// irsim: infrared images of small aircraft against the sky, with exact ground truth.
#[derive(Debug, Parser)]
#[command(name = "irsim", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Top-level commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Compute one radiometric quantity and print it as JSON.
    #[command(subcommand)]
    Calc(calc::CalcCommand),
    /// Simulate a scenario and write frames, labels, MOT ground truth and a manifest.
    Record(run::RecordArgs),
    /// Draw the sequences of a dataset spec and record them (all, or one shard's).
    Dataset(dataset::DatasetArgs),
    /// Check a scenario file and report the first error with file, line, column and field.
    Validate(run::ValidateArgs),
    /// Generate an infrared sky image (16-bit PNG).
    Sky(run::SkyArgs),
    /// Frames per second of the whole pipeline on built-in scenarios.
    Bench(run::BenchArgs),
    /// Fly a scenario in a window: the live sensor image, a 3D view of the encounter, play/pause/step/seek.
    #[cfg(feature = "gui")]
    View(crate::ui::ViewArgs),
}

/// Writes `text` and a newline to standard output: a closed pipe (`irsim validate S | head -1`) or a full disk is
/// a failure with its reason (exit 1), not a panic.
///
/// # Errors
/// [`CliError::Failed`] when standard output cannot be written.
pub(crate) fn say(text: &str) -> Result<(), CliError> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{text}").map_err(|e| CliError::Failed(format!("writing to standard output: {e}")))
}

/// Parses `args`, runs the command and returns the process exit code.
pub fn run<I, T>(args: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    let result = match &cli.command {
        Command::Calc(cmd) => calc::run(cmd).and_then(|value| say(&value.to_string())),
        Command::Record(a) => run::record(a),
        Command::Dataset(a) => dataset::dataset(a),
        Command::Validate(a) => run::validate(a),
        Command::Sky(a) => run::sky(a),
        Command::Bench(a) => run::bench(a),
        #[cfg(feature = "gui")]
        Command::View(a) => crate::ui::view(a),
    };
    match result {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {e}");
            e.exit_code()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--help` is made from the doc comments, which rustdoc reads too: an intra-doc link there reaches the user
    /// as `[`crate::…`]`. Every command's and subcommand's long help, its options' and their values' included,
    /// must read as plain text.
    #[test]
    fn help_texts_hold_no_rustdoc_links() {
        use clap::CommandFactory;
        fn check(cmd: &mut clap::Command, path: &str) -> usize {
            let help = cmd.render_long_help().to_string();
            for bad in ["[`", "`]", "crate::", "](", "super::"] {
                assert!(!help.contains(bad), "`{path} --help` holds {bad:?}:\n{help}");
            }
            let mut seen = 1;
            for sub in cmd.get_subcommands_mut() {
                let name = format!("{path} {}", sub.get_name());
                seen += check(sub, &name);
            }
            seen
        }
        let mut cli = Cli::command();
        cli.build();
        // every command is looked at, not only the top level's list
        assert!(check(&mut cli, "irsim") > 8);
    }
}
