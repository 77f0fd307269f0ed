//! The headless front end: an [`App`] with `MinimalPlugins` (without `TaskPoolPlugin`'s polling every update)
//! that computes one sensor frame per `update()`, and the helpers tests, the recorder and the benchmark drive it
//! with.

use bevy::app::{App, PluginGroup, TaskPoolPlugin};
use bevy::ecs::message::Messages;
use bevy::ecs::prelude::*;
use bevy::prelude::MinimalPlugins;
use bevy::tasks::{AsyncComputeTaskPool, ComputeTaskPool, IoTaskPool, TaskPool};
use bevy::time::{Fixed, Time, TimeUpdateStrategy};

use super::{FramePool, FrameReady, Fusion, IrSimPlugins, RunOptions, SetupError, TimingPlugin, spawn_scenario};
use crate::imaging::frame::Frame;
use crate::labels::FrameLabels;
use crate::scenario::CheckedScenario;

/// Bevy's fixed timestep in every app: one step per `update()` whatever the sensor's frame rate (the
/// simulation's own time is [`SimClock`](super::SimClock)).
pub const BEVY_STEP: std::time::Duration = std::time::Duration::from_millis(10);

/// A headless app for `scenario`: `MinimalPlugins` without `TaskPoolPlugin` (Bevy's task pools made
/// directly), [`IrSimPlugins`] (and [`TimingPlugin`] if asked), the scenario spawned, one fixed step per
/// `update()`, warmed up (the first update runs Startup and no fixed step), so each further `update()` computes
/// one frame and writes one [`FrameReady`].
///
/// # Errors
/// [`SetupError`] if the sky image cannot be loaded or placed, or the PSF built.
pub fn headless_app(scenario: &CheckedScenario, options: RunOptions) -> Result<App, SetupError> {
    let mut app = App::new();
    // Bevy's task pools without `TaskPoolPlugin`, whose system in `Last` polls each pool's local executor 100
    // times every update (300 polls of empty queues, ~3 µs a frame): no system here spawns a Bevy task (the
    // stages parallelize with rayon)
    app.add_plugins(MinimalPlugins.build().disable::<TaskPoolPlugin>());
    ComputeTaskPool::get_or_init(TaskPool::default);
    AsyncComputeTaskPool::get_or_init(TaskPool::default);
    IoTaskPool::get_or_init(TaskPool::default);
    // Simulated time is `SimClock`'s (t0 + k/rate, exact at any rate); Bevy's clock only has to run one fixed
    // step per update, which a nominal step below its 250 ms maximum delta does at every frame rate.
    app.insert_resource(Time::<Fixed>::from_duration(BEVY_STEP));
    app.insert_resource(TimeUpdateStrategy::FixedTimesteps(1));
    app.add_plugins(IrSimPlugins);
    if options.timings {
        app.add_plugins(TimingPlugin);
    }
    run_systems_in_order(&mut app);
    spawn_scenario(app.world_mut(), scenario, options)?;
    app.update();
    Ok(app)
}

/// Runs every schedule of `app` on one thread, system after system. The simulation's systems form one chain and
/// parallelize inside themselves (rayon over rows and tiles); with Bevy's `multi_threaded` feature on (the window
/// build turns it on for pipelined rendering) the default multi-threaded executor only adds hand-offs between
/// threads to every system, which made `irsim bench`'s 256×256 case 15–35 % slower.
pub fn run_systems_in_order(app: &mut App) {
    for (_, schedule) in app.world_mut().resource_mut::<Schedules>().iter_mut() {
        schedule.set_executor(bevy::ecs::schedule::SingleThreadedExecutor::new());
    }
}

/// [`headless_app`] under its earlier name.
///
/// # Errors
/// As [`headless_app`].
pub fn build_app(scenario: &CheckedScenario, options: RunOptions) -> Result<App, SetupError> {
    headless_app(scenario, options)
}

/// Lets `flag` stop the run inside a frame: long iterative fusion solves look at it between sweeps. A frame
/// computed while it was set is incomplete; the caller must not write it.
pub fn set_stop_flag(app: &mut App, flag: std::sync::Arc<std::sync::atomic::AtomicBool>) {
    app.world_mut().resource_mut::<Fusion>().0.set_stop(flag);
}

/// The frames [`FrameReady`] carried out of the schedule since the last call, oldest first.
pub fn drain_frames(app: &mut App) -> Vec<FrameReady> {
    drain_frames_world(app.world_mut())
}

/// [`drain_frames`] on a world.
pub fn drain_frames_world(world: &mut World) -> Vec<FrameReady> {
    world.resource_mut::<Messages<FrameReady>>().drain().collect()
}

/// Computes frame `k` directly and returns it: the clock is set to `k` and one step runs. Trajectories and
/// vibration are analytic in time and the noise of frame `k` is drawn from its own stream, so this is the frame
/// a run from frame 0 writes as frame `k` (the viewer's seek, and its tests, rely on it).
pub fn frame_at(app: &mut App, k: u64) -> Option<FrameReady> {
    app.world_mut().resource_mut::<super::SimClock>().frame = k;
    app.update();
    drain_frames(app).pop()
}

/// Runs `f` (one frame) with rayon's other workers kept awake: each is given a job of its own (a broadcast) that
/// looks for work in the pool until `f` returns, so the frame's parallel stages find them ready instead of waking
/// them from sleep (rayon puts an idle worker to sleep within microseconds; handing each frame to a pool thread and
/// back cost about 110 µs here, a third of a 256×256 frame). A waiting worker calls the system's yield between
/// looks. Outside a pool, or in a pool of one, `f` just runs.
pub fn with_workers_awake<R>(f: impl FnOnce() -> R) -> R {
    with_workers_awake_and(None, f)
}

/// Idle work for [`with_workers_awake_and`]: does one piece of work on the calling thread and says whether there
/// was any.
pub type IdleWork = std::sync::Arc<dyn Fn() -> bool + Send + Sync>;

thread_local! {
    /// Whether this thread is inside a waiting worker's idle work (whose pauses may run another waiting job).
    static IN_IDLE_WORK: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    /// A later frame's end flag, left by that frame's waiting job when it ran inside this thread's idle work:
    /// the waiting loop that did the idle work goes on waiting for that frame instead of ending with its own.
    static ADOPTED: std::cell::RefCell<Option<std::sync::Arc<std::sync::atomic::AtomicBool>>> =
        const { std::cell::RefCell::new(None) };
}

/// [`with_workers_awake`], the waiting workers doing `idle` (the recorder's frames to encode) when the pool has
/// nothing for them, in place of the system's yield. Work that `idle` does should pause for the pool's jobs
/// now and then (`rayon::yield_now`), so that the frame's parallel stages are not kept waiting by it. The
/// waiting jobs are not scoped to `f`: when `f` returns they stop at their next look, and one in the middle
/// of idle work finishes that piece without holding up the caller.
pub fn with_workers_awake_and<R>(idle: Option<&IdleWork>, f: impl FnOnce() -> R) -> R {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    let (Some(owner), others) = (rayon::current_thread_index(), rayon::current_num_threads().saturating_sub(1)) else {
        return f();
    };
    if others == 0 {
        return f();
    }
    let done = Arc::new(AtomicBool::new(false));
    let (waiting, idle) = (Arc::clone(&done), idle.cloned());
    // one job on each thread of the pool, which no other thread can take: a job that the frame's own thread ran
    // (and so dropped) would leave a worker without its waiting loop until `f` returns, for a whole recording
    // where `f` is the recording's loop
    rayon::spawn_broadcast(move |ctx| {
        // the frame's own thread runs its job while it waits in a join, or after `f`; idle work pausing for
        // the pool may run this thread's: neither must wait here
        if ctx.index() == owner {
            return;
        }
        let (done, idle) = (Arc::clone(&waiting), idle.clone());
        if IN_IDLE_WORK.get() {
            ADOPTED.set(Some(done));
            return;
        }
        let mut done = done;
        while !done.load(Ordering::Acquire) {
            if rayon::yield_now() == Some(rayon::Yield::Executed) {
                continue;
            }
            let worked = idle.as_ref().is_some_and(|work| {
                // cleared however `work` ends
                struct Idle;
                impl Drop for Idle {
                    fn drop(&mut self) {
                        IN_IDLE_WORK.set(false);
                    }
                }
                IN_IDLE_WORK.set(true);
                let _idle = Idle;
                work()
            });
            if let Some(later) = ADOPTED.take() {
                done = later;
            }
            if !worked {
                std::thread::yield_now();
            }
        }
    });
    // set even if `f` panics, so that the waiting jobs end
    struct Done(Arc<AtomicBool>);
    impl Drop for Done {
        fn drop(&mut self) {
            self.0.store(true, Ordering::Release);
        }
    }
    let _done = Done(done);
    f()
}

/// The frame [`step`] read last (its buffer goes back to the [`FramePool`] when the next one arrives).
#[derive(Resource, Debug, Default)]
pub struct LatestFrame(pub Option<FrameReady>);

/// Runs one step (one frame) and returns its labels; the frame stays readable through [`current_frame`].
///
/// # Panics
/// If the step produced no frame (the scenario's entities are missing).
pub fn step(app: &mut App) -> FrameLabels {
    // the frame's systems run on a thread of rayon's pool, so that each parallel stage forks from a worker
    // (the other workers steal its halves) instead of handing the whole stage over to the pool and sleeping
    // until it is done (the `irsim` program's main thread is a worker already)
    let sub_apps = app.sub_apps_mut();
    if sub_apps.sub_apps.is_empty() && rayon::current_thread_index().is_none() {
        // what `App::update` does for an app without sub-apps
        let main = &mut sub_apps.main;
        rayon::scope(|_| with_workers_awake(|| main.update()));
    } else {
        with_workers_awake(|| app.update());
    }
    let ready = drain_frames(app).pop().expect("each step completes one frame");
    let labels = ready.labels.clone();
    let world = app.world_mut();
    let previous = world.get_resource_or_init::<LatestFrame>().0.replace(ready);
    if let Some(old) = previous {
        world.get_resource_or_init::<FramePool>().give_back(old.frame);
    }
    labels
}

/// The sensor frame of the last [`step`] (quantized DN as f32).
///
/// # Panics
/// Before the first [`step`].
pub fn current_frame(app: &mut App) -> &Frame {
    &app.world().resource::<LatestFrame>().0.as_ref().expect("a step has run").frame
}

#[cfg(test)]
mod tests {
    use super::with_workers_awake;

    #[test]
    fn a_panicking_frame_releases_the_waiting_workers() {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        // the panic reaches the caller (the waiting job is not scoped to the frame: it sees the frame's end flag,
        // set as the panic passes, and stops); the frame waits until the other thread has run part of it, which it can only reach by first taking
        // the waiting job (pushed before, at the end of the queue that thieves take from)
        let caught = pool.install(|| {
            std::panic::catch_unwind(|| {
                with_workers_awake(|| -> u64 {
                    use std::sync::atomic::{AtomicBool, Ordering};
                    let flag = AtomicBool::new(false);
                    rayon::join(
                        || {
                            while !flag.load(Ordering::Acquire) {
                                std::hint::spin_loop();
                            }
                        },
                        || flag.store(true, Ordering::Release),
                    );
                    panic!("a frame")
                })
            })
        });
        assert!(caught.is_err());
        // a frame that ends gives its value, its parallel work done by both threads
        let sum: u64 = pool.install(|| {
            with_workers_awake(|| {
                use rayon::prelude::*;
                (0..100_000u32).into_par_iter().with_max_len(1000).map(u64::from).sum()
            })
        });
        assert_eq!(sum, 4_999_950_000);
        // in a pool of one, and outside any pool, it only runs the frame
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        assert_eq!(one.install(|| with_workers_awake(|| 7)), 7);
        assert_eq!(with_workers_awake(|| 8), 8);
    }
}
