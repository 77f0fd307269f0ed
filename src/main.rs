//! The `irsim` program; see `irsim --help`.

fn main() {
    // The main thread is worker 0 of rayon's global pool: the simulation's systems run on it, so each parallel
    // stage of a frame forks from a worker (the others steal its halves) instead of handing the stage to the
    // pool and sleeping until the pool's threads are done; no thread hand-off is left per frame or per stage.
    // (`RAYON_NUM_THREADS` still sets the pool's size, the main thread included.)
    // Not for the viewer: its main thread runs the window's event loop, outside rayon, while a recording
    // started from the window runs on a thread of its own; with one thread in the pool nothing would run its
    // parallel stages.
    let viewer =
        std::env::args_os().skip(1).find(|a| !a.to_string_lossy().starts_with('-')).is_some_and(|a| a == "view");
    if !viewer {
        let _ = rayon::ThreadPoolBuilder::new().use_current_thread().build_global();
    }
    std::process::exit(irsim::cli::run(std::env::args_os()));
}
