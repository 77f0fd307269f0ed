//! The `irsim` program; see `irsim --help`.

fn main() {
    std::process::exit(irsim::cli::run(std::env::args_os()));
}
