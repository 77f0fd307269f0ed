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
/// looks for work in the pool until `f` returns (details, and when a worker is not held: [`with_workers_awake_and`]),
/// so the frame's parallel stages find them ready instead of waking them from sleep (rayon puts an idle worker to
/// sleep within microseconds; handing each frame to a pool thread and back cost about 110 µs here, a third of a
/// 256×256 frame). A waiting worker calls the system's yield between looks. Outside a pool, or in a pool of one,
/// `f` just runs.
pub fn with_workers_awake<R>(f: impl FnOnce() -> R) -> R {
    awake_while(None, FRAME_START_WAIT, f)
}

/// Idle work for [`with_workers_awake_and`]: does one piece of work on the calling thread and says whether there
/// was any.
pub type IdleWork = std::sync::Arc<dyn Fn() -> bool + Send + Sync>;

/// How long a waiting loop goes on looking for work after the frames it waits for have ended: a frame run right
/// after (the next `step`) finds the worker still awake and its waiting job taken up by this loop at once.
const LINGER: std::time::Duration = std::time::Duration::from_micros(200);

/// How long [`with_workers_awake`] waits for every other worker to take up its waiting job before it runs the
/// frame anyway. A worker still in its waiting loop from the frame before takes it up within a microsecond or two;
/// one asleep, or not given a core (a loaded machine), may take far longer, and that frame runs without it kept
/// awake rather than wait.
const FRAME_START_WAIT: std::time::Duration = std::time::Duration::from_micros(100);

/// The same wait for [`with_workers_awake_and`], which holds the workers awake over a long `f` (a whole
/// recording): worth waiting for a sleeping worker to wake.
const LOOP_START_WAIT: std::time::Duration = std::time::Duration::from_millis(20);

thread_local! {
    /// Whether a waiting loop runs on this thread (further down its stack): a waiting job that starts inside it
    /// hands its end flag to that loop instead of waiting itself.
    static WAITING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    /// Whether this thread runs the frame of a [`with_workers_awake_and`], or waits for its workers before it
    /// (further down its stack): another frame's waiting job that it takes up there ends at once.
    static IN_FRAME: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    /// Frames whose waiting jobs started inside this thread's waiting loop, for that loop to wait for.
    static ADOPTED: std::cell::RefCell<Vec<std::sync::Arc<FrameFlags>>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Sets a thread-local flag for its lifetime, and restores it however the scope ends.
struct FlagScope(&'static std::thread::LocalKey<std::cell::Cell<bool>>, bool);

impl FlagScope {
    fn set(key: &'static std::thread::LocalKey<std::cell::Cell<bool>>) -> Self {
        Self(key, key.replace(true))
    }
}

impl Drop for FlagScope {
    fn drop(&mut self) {
        self.0.set(self.1);
    }
}

/// [`with_workers_awake`], the waiting workers doing `idle` (the recorder's frames to encode) when the pool has
/// nothing for them, in place of the system's yield. Work that `idle` does should pause for the pool's jobs
/// now and then (`rayon::yield_now`), so that the frame's parallel stages are not kept waiting by it. The
/// waiting jobs are not scoped to `f`: when `f` returns they stop at their next look (after lingering a little
/// for a next frame), and one in the middle of idle work finishes that piece without holding up the caller.
///
/// A waiting loop must never have beneath it a part of a frame it waits for: the frame would wait for that part,
/// and the loop for the frame's end. A worker that looked for work just before its job arrived can take a part of
/// the frame first, and then the job while that part waits in a join. So a waiting job loops only where that
/// cannot be: one that starts inside a waiting loop hands its flag to that loop, one that starts on a thread
/// running (or about to run) another frame ends at once, and one that starts after `f` has begun ends at once
/// (that worker is then not held awake for this `f`: for a recording, one that takes its job more than the
/// start wait late does not encode). `f` begins once every other worker has taken up its job (or after 20 ms;
/// [`with_workers_awake`]: 100 µs), and a worker's loop lingers 200 µs after its frames end, so that the next
/// frame's job is taken up inside it. A loop does only the idle work of the job that started it.
pub fn with_workers_awake_and<R>(idle: Option<&IdleWork>, f: impl FnOnce() -> R) -> R {
    awake_while(idle, LOOP_START_WAIT, f)
}

/// [`with_workers_awake_and`], waiting at most `start_wait` for the workers to take up their jobs.
fn awake_while<R>(idle: Option<&IdleWork>, start_wait: std::time::Duration, f: impl FnOnce() -> R) -> R {
    use std::sync::Arc;
    use std::sync::atomic::Ordering;
    let (Some(owner), others) = (rayon::current_thread_index(), rayon::current_num_threads().saturating_sub(1)) else {
        return f();
    };
    if others == 0 {
        return f();
    }
    let frame = Arc::new(FrameFlags::default());
    let (job_frame, idle) = (Arc::clone(&frame), idle.cloned());
    // one job on each thread of the pool, which no other thread can take: a job that the frame's own thread ran
    // (and so dropped) would leave a worker without its waiting loop until `f` returns, for a whole recording
    // where `f` is the recording's loop
    rayon::spawn_broadcast(move |ctx| {
        // the frame's own thread runs its job while it waits in a join, or after `f`: it must not wait here
        if ctx.index() == owner {
            return;
        }
        // read before this job counts itself as taken: `f` begins as soon as every job is counted, so a read after
        // the count would find it begun, and the worker not held, whenever `f` won that race (for a recording,
        // whose loop is one `f`, a worker never held for the whole run); begun not yet when the job started
        // means no part of `f` can be beneath it
        let late = job_frame.begun.load(Ordering::SeqCst);
        job_frame.taken.fetch_add(1, Ordering::SeqCst);
        if IN_FRAME.get() {
            return;
        }
        if WAITING.get() {
            ADOPTED.with_borrow_mut(|a| a.push(Arc::clone(&job_frame)));
            return;
        }
        if late {
            return;
        }
        let _waiting = FlagScope::set(&WAITING);
        wait_for_frames(Arc::clone(&job_frame), idle.as_ref());
    });
    // set even if `f` panics, so that the waiting jobs end
    struct Done(Arc<FrameFlags>);
    impl Drop for Done {
        fn drop(&mut self) {
            self.0.done.store(true, Ordering::Release);
        }
    }
    let _done = Done(Arc::clone(&frame));
    // set before the wait: another caller's waiting job taken here must end at once (looping on top of this
    // frame's wait, it would hold the frame until that caller's frames end, or for ever if that caller's frame is
    // held the same way by this one's)
    let _in_frame = FlagScope::set(&IN_FRAME);
    let since = std::time::Instant::now();
    while frame.taken.load(Ordering::SeqCst) < others && since.elapsed() < start_wait {
        // this thread's own waiting job, and other callers' frames' jobs, are taken here
        if rayon::yield_local() != Some(rayon::Yield::Executed) {
            std::hint::spin_loop();
        }
    }
    frame.begun.store(true, Ordering::SeqCst);
    f()
}

/// One call's state, shared with its waiting jobs.
#[derive(Default)]
struct FrameFlags {
    /// The other workers that have taken up their jobs (looping, handing the frame to a loop, or ending).
    taken: std::sync::atomic::AtomicUsize,
    /// `f` has begun: a job taken up later ends at once.
    begun: std::sync::atomic::AtomicBool,
    /// `f` has returned (or panicked).
    done: std::sync::atomic::AtomicBool,
}

/// A worker's waiting loop: looks for the pool's jobs (then `idle`, then the system's yield) until every frame
/// it waits for has ended (its own, and those whose waiting jobs started inside it), and [`LINGER`] after.
fn wait_for_frames(frame: std::sync::Arc<FrameFlags>, idle: Option<&IdleWork>) {
    use std::sync::atomic::Ordering;
    let mut frames = vec![frame];
    let mut ended: Option<std::time::Instant> = None;
    loop {
        frames.retain(|f| !f.done.load(Ordering::Acquire));
        if frames.is_empty() {
            let at = *ended.get_or_insert_with(std::time::Instant::now);
            if at.elapsed() >= LINGER {
                return;
            }
        } else {
            ended = None;
        }
        let executed = rayon::yield_now() == Some(rayon::Yield::Executed);
        let worked = executed || (!frames.is_empty() && idle.is_some_and(|work| work()));
        ADOPTED.with_borrow_mut(|a| frames.append(a));
        if !worked {
            std::thread::yield_now();
        }
    }
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
    use super::{LOOP_START_WAIT, with_workers_awake};

    /// Runs `f` on a thread of its own and returns its value, failing if it has not returned within `seconds`.
    fn finishes_within<T: Send + 'static>(seconds: u64, f: impl FnOnce() -> T + Send + 'static) -> T {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(f());
        });
        rx.recv_timeout(std::time::Duration::from_secs(seconds)).expect("the frames did not finish")
    }

    #[test]
    fn a_panicking_frame_releases_the_waiting_workers() {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        // the panic reaches the caller (the waiting job is not scoped to the frame: it sees the frame's end flag,
        // set as the panic passes, and stops); the frame waits until the other thread has run part of it
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

    /// Frame `k` of a test: parallel parts that fork again (as the radiometry's targets do), then `tail_us` of
    /// work on the frame's own thread; its sum.
    fn test_frame(k: u32, tail_us: u64) -> f64 {
        use rayon::prelude::*;
        let sum = (0..8u32)
            .into_par_iter()
            .map(|i| {
                let v: Vec<f64> = (0..256u32)
                    .into_par_iter()
                    .with_max_len(16)
                    .map(|j| f64::from(i * 256 + j + k).sqrt().ln_1p())
                    .collect();
                v.iter().sum::<f64>()
            })
            .sum::<f64>();
        let t = std::time::Instant::now();
        while t.elapsed() < std::time::Duration::from_micros(tail_us) {
            std::hint::spin_loop();
        }
        sum
    }

    /// What [`test_frame`]s `0..frames` sum to.
    fn test_frames_sum(frames: u32) -> f64 {
        (0..frames).map(|k| (0..2048u32).map(|n| f64::from(n + k).sqrt().ln_1p()).sum::<f64>()).sum()
    }

    #[test]
    fn the_other_worker_is_held_for_the_whole_call() {
        // a long `f` (a recording's loop) is started as soon as the other worker has taken its job, and that worker
        // must then stay in its waiting loop, doing the idle work, for all of `f`: one that saw `f` begun in the
        // race with its own count would leave, and a recording's frames would all be encoded by the frame's thread
        use std::sync::Arc;
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::time::{Duration, Instant};
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let (prompt, dropped) = pool.install(|| {
            let (mut prompt, mut dropped) = (0, 0);
            // one idle work for every call (a loop that lingers from the last call and adopts this one's job does the
            // idle work of the job that started it): it marks the call under way as seen by the other worker
            let owner = rayon::current_thread_index();
            let (call, seen) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
            let (now, mark) = (Arc::clone(&call), Arc::clone(&seen));
            let idle: super::IdleWork = Arc::new(move || {
                if rayon::current_thread_index() != owner {
                    mark.store(now.load(Ordering::SeqCst), Ordering::SeqCst);
                }
                false
            });
            for k in 1..=200 {
                // mostly past the linger of the last call's loop, so that most calls start the loop afresh
                std::thread::sleep(Duration::from_millis(1));
                call.store(k, Ordering::SeqCst);
                let called = Instant::now();
                let waited = super::with_workers_awake_and(Some(&idle), || {
                    let waited = called.elapsed();
                    let t = Instant::now();
                    while seen.load(Ordering::SeqCst) != k && t.elapsed() < Duration::from_millis(200) {
                        std::hint::spin_loop();
                    }
                    waited
                });
                // `f` begun well inside the start wait: the worker had taken its job before, so it must be held (one
                // not given a core within the start wait, on a loaded machine, is rightly not held)
                if waited < LOOP_START_WAIT / 2 {
                    prompt += 1;
                    dropped += usize::from(seen.load(Ordering::SeqCst) != k);
                }
            }
            (prompt, dropped)
        });
        assert_eq!(dropped, 0, "the other worker took its job in time but left in {dropped} of {prompt} calls");
        if prompt < 20 {
            eprintln!("only {prompt} of 200 calls began inside the start wait: a loaded machine tests little here");
        }
    }

    #[test]
    fn frames_run_back_to_back_with_nested_parallel_work_all_finish() {
        // a worker that looks for work as a frame starts must not take a part of it before its waiting job (which
        // would then wait on top of that part, for the frame's end)
        let frames = 5000;
        let total = finishes_within(240, move || {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
            pool.install(|| (0..frames).map(|k| with_workers_awake(|| test_frame(k, 0))).sum::<f64>())
        });
        let expected = test_frames_sum(frames);
        assert!((total - expected).abs() <= 1e-9 * expected, "{total} vs {expected}");
    }

    #[test]
    fn frames_of_two_callers_on_one_pool_all_finish() {
        // two threads each run frames back to back in one pool (of 2, then of 4): a thread waiting for its frame's
        // workers takes the other caller's waiting jobs, which must not wait there
        for threads in [2, 4] {
            let frames = 300;
            let totals = finishes_within(60, move || {
                let pool = std::sync::Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap());
                let callers: Vec<_> = (0..2)
                    .map(|_| {
                        let pool = std::sync::Arc::clone(&pool);
                        std::thread::spawn(move || {
                            pool.install(|| (0..frames).map(|k| with_workers_awake(|| test_frame(k, 50))).sum::<f64>())
                        })
                    })
                    .collect();
                callers.into_iter().map(|c| c.join().unwrap()).collect::<Vec<f64>>()
            });
            let expected = test_frames_sum(frames);
            for total in totals {
                assert!((total - expected).abs() <= 1e-9 * expected, "{threads} threads: {total} vs {expected}");
            }
        }
    }

    #[test]
    fn frames_started_inside_other_frames_parts_all_finish() {
        // each part of a frame runs frames of its own: a thread that runs one frame takes another's waiting job
        // while it waits in a join, which must not wait there
        use rayon::prelude::*;
        let total = finishes_within(120, || {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
            pool.install(|| {
                (0..200u64)
                    .map(|k| {
                        with_workers_awake(|| {
                            (0..8u32)
                                .into_par_iter()
                                .with_max_len(1)
                                .map(|i| {
                                    with_workers_awake(|| {
                                        (0..64u32)
                                            .into_par_iter()
                                            .with_max_len(1)
                                            .map(|j| u64::from(i * j) + k)
                                            .sum::<u64>()
                                    })
                                })
                                .sum::<u64>()
                        })
                    })
                    .sum::<u64>()
            })
        });
        // per frame: sum over i < 8, j < 64 of i·j (28 · 2016) plus 512 k
        let expected: u64 = (0..200u64).map(|k| 28 * 2016 + 512 * k).sum();
        assert_eq!(total, expected);
    }
}
