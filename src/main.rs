//! The `irsim` program; see `irsim --help`.

fn main() {
    // The main thread is worker 0 of rayon's global pool: the simulation's systems run on it, so each parallel
    // stage of a frame forks from a worker (the others steal its halves) instead of handing the stage to the
    // pool and sleeping until the pool's threads are done; no thread hand-off is left per frame or per stage.
    // (`RAYON_NUM_THREADS` still sets the pool's size, the main thread included.)
    let _ = rayon::ThreadPoolBuilder::new().use_current_thread().build_global();
    std::process::exit(irsim::cli::run(std::env::args_os()));
}
