//! Recording a run: frames encoded in rayon's pool, labels, MOT ground truth and a manifest, all written
//! atomically (each given its name only when whole).
//!
//! A frame's encoding and writing is done by the threads of the simulation's own pool, not by threads of their own: on
//! a machine with few cores, threads of their own competed with the pool's workers for the cores, and a worker waiting
//! for its share of a parallel stage spun while an encoder held its core. Frames wait in an [`EncodeQueue`]; a worker
//! that the frame's stages leave idle encodes one (see [`crate::sim::with_workers_awake_and`], which holds the workers
//! awake for the whole recording loop), looking for the pool's jobs every [`PAUSE_BYTES`] of the frame, and the
//! simulation's thread encodes one itself when too many wait. Outside a pool, and for the formats whose encoders do not
//! pause (all but 16-bit PNG at `fast`), each frame is a task of the pool instead.
//!
//! [`PAUSE_BYTES`]: crate::imaging::png16::PAUSE_BYTES
//!
//! Frames are committed in order: the labels on disk always describe exactly the frames on disk. The labels and MOT
//! lines are appended and put in place, and the manifest rewritten, at checkpoints (every second) and at the end, so an interruption (Ctrl-C,
//! SIGTERM, SIGHUP) or a write error (disk full) leaves complete frames, matching labels, and a manifest whose
//! `status` and `frames_written` say where the run stopped.
//!
//! Durability is paid once per checkpoint, not per file: the thread encoding a frame writes it to a file without a name
//! and links it under its name on Linux (elsewhere, or where the file system cannot, to a temporary file renamed into
//! place), so that a file under a frame's name is always whole, even after `kill -9`, without waiting for the disk; a
//! thread of its own (`Writeback`, on Linux) starts the disk on the files written every tenth of a second, so that the
//! last checkpoint's sync finds little left to write; each checkpoint first makes everything written since the last one
//! durable, then puts the labels in place. On Linux that sync is one `syncfs` of the output's file system (through the
//! directory opened when the recording began, so that a write-back error on any file since then is reported) while the
//! machine holds little else waiting to be written, and a sync of each file and of its directory otherwise, so that a
//! recording waits for at most a few milliseconds of other programs' writes (a build's output); elsewhere always the
//! latter (`SyncWay`). The labels and the MOT lines are each appended, before that sync, to one of two hidden files
//! that take turns being linked in place under the file's name (`ShadowedText`): a checkpoint writes the lines since
//! the last but one, not the whole text, and a recording keeps only those in memory. The manifest is written under a
//! temporary name before the sync; after it, the labels, the MOT file and the manifest are put in place; the last
//! checkpoint removes the hidden files and syncs once more, for the names. A checkpoint during the run is written by a
//! thread of its own from a copy of the lines it appends, so the simulation does not wait for the disk (a checkpoint
//! still being written when the next is due delays that one); the last one, at the end, is waited for. A crash of the
//! machine loses at most the frames since the last checkpoint, and never leaves labels that list a frame the disk does
//! not hold. A checkpoint writes the labels, then the MOT file, then the manifest, so a process killed in the middle of
//! one (`kill -9`) may leave the manifest's `frames_written` one checkpoint behind the labels, never ahead of them.

use std::collections::BTreeMap;
use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::Serialize;

use crate::imaging::agc::{Agc, AgcSpec};
use crate::imaging::frame::{Frame, PngCompression};
use crate::imaging::png16::Png16Encoder;
use crate::labels::FrameLabels;

/// How frames are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum FrameFormat {
    /// 16-bit grayscale PNG at the sensor's levels.
    Png16,
    /// 8-bit grayscale PNG, the sensor's range scaled to 0–255.
    Png8,
    /// 8-bit grayscale PNG through an AGC: a percentile stretch (0.5–99.5 %) smoothed over frames, as most
    /// real datasets were recorded.
    #[value(name = "png8-agc")]
    #[serde(rename = "png8_agc")]
    Png8Agc,
    /// float32 `.npy` before quantization.
    Npy,
}

impl FrameFormat {
    fn extension(self) -> &'static str {
        match self {
            FrameFormat::Png16 | FrameFormat::Png8 | FrameFormat::Png8Agc => "png",
            FrameFormat::Npy => "npy",
        }
    }
}

/// An error preparing or writing the output.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The output directory holds files and `--force` was not given.
    #[error("{0} is not empty; use --force to replace its contents")]
    NotEmpty(String),
    /// The output path exists and is not a directory (never replaced, even with `--force`).
    #[error("{0} exists and is not a directory; give --out a directory")]
    NotADirectory(String),
    /// Another recording holds the output directory's lock.
    #[error("{0} is in use by another recording (process {1}); if none is running, remove {0}/{LOCK_FILE}")]
    Locked(String, String),
    /// An I/O error, with the path.
    #[error("{path}: {message}")]
    Io {
        /// The file or directory.
        path: String,
        /// What failed.
        message: String,
    },
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> RecordError {
    RecordError::Io { path: path.display().to_string(), message: e.to_string() }
}

/// Writes `bytes` to `path` atomically: a temporary file in the same directory, synced, renamed into place.
///
/// # Errors
/// The I/O error with the path.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RecordError> {
    write_through(&temporary_of(path), path, bytes)
}

/// The temporary name `path` is written under before it is renamed into place: `.tmp` added to its extension.
fn temporary_of(path: &Path) -> PathBuf {
    path.with_extension(format!("{}.tmp", path.extension().and_then(|e| e.to_str()).unwrap_or("")))
}

/// A name no other process or call makes: `.{stem}.{process id}.{nanoseconds since 1970}.tmp` (the shape
/// [`is_leftover`] recognizes for `frames` and `masks`).
fn fresh_name(stem: &str) -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    format!(".{stem}.{}.{nanos}.tmp", std::process::id())
}

/// Writes `bytes` to `f`, calling `pause` before every [`PAUSE_BYTES`] of them.
///
/// [`PAUSE_BYTES`]: crate::imaging::png16::PAUSE_BYTES
fn write_pieces(f: &mut std::fs::File, bytes: &[u8], pause: &mut dyn FnMut()) -> std::io::Result<()> {
    for piece in bytes.chunks(crate::imaging::png16::PAUSE_BYTES) {
        pause();
        f.write_all(piece)?;
    }
    Ok(())
}

/// Writes a recording's file `path` whole, without syncing it: unnamed and linked where `unnamed` holds
/// ([`write_unnamed_pausing`]), else under its temporary name and renamed; `pause` as in [`write_renamed_pausing`].
/// Returns the file, still open, where it was written unnamed.
fn write_whole_pausing(
    path: &Path,
    bytes: &[u8],
    pause: &mut dyn FnMut(),
    unnamed: &std::sync::atomic::AtomicBool,
) -> Result<Option<std::fs::File>, RecordError> {
    match write_unnamed_pausing(path, bytes, pause, unnamed) {
        Some(f) => Ok(Some(f)),
        None => write_renamed_pausing(&temporary_of(path), path, bytes, false, pause).map(|()| None),
    }
}

/// Writes `bytes` to `tmp`, syncs it and renames it to `path`; `tmp` is removed on failure.
fn write_through(tmp: &Path, path: &Path, bytes: &[u8]) -> Result<(), RecordError> {
    write_renamed(tmp, path, bytes, true)
}

/// Writes `bytes` to `tmp`, syncs it if `sync`, and renames it to `path`; `tmp` is removed on failure.
fn write_renamed(tmp: &Path, path: &Path, bytes: &[u8], sync: bool) -> Result<(), RecordError> {
    write_renamed_pausing(tmp, path, bytes, sync, &mut || {})
}

/// [`write_renamed`], calling `pause` between the system calls and after every [`PAUSE_BYTES`] written.
///
/// [`PAUSE_BYTES`]: crate::imaging::png16::PAUSE_BYTES
fn write_renamed_pausing(
    tmp: &Path,
    path: &Path,
    bytes: &[u8],
    sync: bool,
    pause: &mut dyn FnMut(),
) -> Result<(), RecordError> {
    let result = (|| {
        let mut f = std::fs::File::create(tmp)?;
        write_pieces(&mut f, bytes, pause)?;
        if sync {
            f.sync_data()?;
        }
        drop(f);
        pause();
        std::fs::rename(tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(tmp);
        io_err(path, e)
    })
}

/// Writes `bytes` under `path`, Linux: into a file without a name in `path`'s directory (`O_TMPFILE`), given its
/// name when it is whole (`linkat`), so that, as with a temporary file renamed into place, a file under `path` is
/// always complete, and a process killed before the link leaves nothing behind. One directory entry is made, where a
/// rename of a temporary file makes one, removes it and makes another, each after a search of the directory: the
/// kernel's time per frame (system calls, in `perf`) went from 94 to 81 µs, 3000 frames of 256 × 256 png16 on one
/// thread of an AMD EPYC into an ext4 directory. `pause` is called between the system calls and after every
/// [`PAUSE_BYTES`] written.
///
/// Returns the file, still open, or `None` where it could not, and the caller writes the file the other way (whose
/// errors say why, if the cause was not this way's). Where the cause would come again for every file (no `O_TMPFILE` in
/// the kernel or the file system; a link refused for any reason but the name being taken: no `/proc`, through which the
/// link names the file, or a sandbox refusing the call), `unnamed` is cleared, so that the run's later files go the
/// other way at once.
///
/// [`PAUSE_BYTES`]: crate::imaging::png16::PAUSE_BYTES
#[cfg(target_os = "linux")]
fn write_unnamed_pausing(
    path: &Path,
    bytes: &[u8],
    pause: &mut dyn FnMut(),
    unnamed: &std::sync::atomic::AtomicBool,
) -> Option<std::fs::File> {
    use std::sync::atomic::Ordering;
    if !unnamed.load(Ordering::Relaxed) {
        return None;
    }
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let mut f = match open_unnamed(dir) {
        Ok(f) => f,
        Err(e) => {
            // EISDIR, EOPNOTSUPP or EINVAL: no O_TMPFILE (an old kernel, or a file system without it)
            if matches!(e.raw_os_error(), Some(libc::EISDIR | libc::EOPNOTSUPP | libc::EINVAL)) {
                unnamed.store(false, Ordering::Relaxed);
            }
            return None;
        }
    };
    write_pieces(&mut f, bytes, pause).ok()?;
    pause();
    let linked = link_unnamed(&f, path);
    if linked.as_ref().is_err_and(|e| e.raw_os_error() != Some(libc::EEXIST)) {
        unnamed.store(false, Ordering::Relaxed);
    }
    linked.ok().map(|()| f)
}

/// A file without a name in `dir`, open for writing (`O_TMPFILE`), asked for with the mode a file made by name is
/// asked for (0o666, less the umask where the kernel applies it: see [`unnamed_files_fit`]).
#[cfg(target_os = "linux")]
fn open_unnamed(dir: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new().write(true).custom_flags(libc::O_TMPFILE).open(dir)
}

/// Gives the unnamed file `f` the name `path` (`linkat` of its descriptor's `/proc/self/fd` entry: unlike a link
/// of the descriptor itself, it needs no privilege).
#[cfg(target_os = "linux")]
fn link_unnamed(f: &std::fs::File, path: &Path) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    use std::os::unix::ffi::OsStrExt;
    let from = std::ffi::CString::new(format!("/proc/self/fd/{}", f.as_raw_fd()))?;
    let to = std::ffi::CString::new(path.as_os_str().as_bytes())?;
    // SAFETY: two NUL-terminated paths that live for the duration of the call
    let linked =
        unsafe { libc::linkat(libc::AT_FDCWD, from.as_ptr(), libc::AT_FDCWD, to.as_ptr(), libc::AT_SYMLINK_FOLLOW) };
    if linked == 0 { Ok(()) } else { Err(std::io::Error::last_os_error()) }
}

/// Whether files written without a name into `dir` ([`write_unnamed_pausing`]) come out as a file made there by
/// name would: one of each is made, and their modes compared (kernels before 6.0 left the umask out of an unnamed
/// file's mode on file systems without ACLs, which would leave frames writable by anyone), and the unnamed one
/// linked (so that a kernel, file system or sandbox that cannot is found once, not at the first frame). Both are
/// removed.
#[cfg(target_os = "linux")]
fn unnamed_files_fit(dir: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    let [named, linked] = ["named", "linked"].map(|what| dir.join(fresh_name(&format!("irsim-probe-{what}"))));
    let mode = |p: &Path| std::fs::metadata(p).map(|m| m.permissions().mode() & 0o7777).ok();
    let fits = (|| {
        std::fs::OpenOptions::new().write(true).create_new(true).open(&named).ok()?;
        let f = open_unnamed(dir).ok()?;
        link_unnamed(&f, &linked).ok()?;
        Some(mode(&named)? == mode(&linked)?)
    })();
    let _ = std::fs::remove_file(&named);
    let _ = std::fs::remove_file(&linked);
    fits == Some(true)
}

/// Elsewhere than Linux: no unnamed files; the caller writes a temporary file and renames it.
#[cfg(not(target_os = "linux"))]
fn write_unnamed_pausing(
    _: &Path,
    _: &[u8],
    _: &mut dyn FnMut(),
    _: &std::sync::atomic::AtomicBool,
) -> Option<std::fs::File> {
    None
}

/// Elsewhere than Linux: no unnamed files.
#[cfg(not(target_os = "linux"))]
fn unnamed_files_fit(_: &Path) -> bool {
    false
}

/// How often [`Writeback`] hands the files written since its last pass to the disk, once the recording has run
/// a while (see [`WRITEBACK_FIRST_WAIT`] for its first passes).
#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
const WRITEBACK_PERIOD: std::time::Duration = std::time::Duration::from_millis(100);

/// The wait before [`Writeback`]'s first pass; each later wait is twice the one before, up to
/// [`WRITEBACK_PERIOD`] (passes 6, 18, 42, 90 and 186 ms into the recording, then every 100 ms). A recording
/// shorter than the period would otherwise leave every file to its last checkpoint's sync, which then writes
/// them all while the simulation has nothing left to do: paper_vibration's 60 frames at 256 × 256 (3.7 MB), a
/// `syncfs` of 8.5–10.7 ms at the end of a 35 ms loop (`strace -f -T`), 0.9–4.9 ms with these waits. Started
/// early, the disk writes them while the frames are computed. Into fresh ext4 directories (AMD EPYC of family
/// 25, 2 vCPUs), alternating runs of `irsim record`, frames/s, medians, every 100 ms against these waits:
/// paper_vibration 1828 → 2072 (8 runs each), 1726 → 2023 and 1828 → 1965 (6), paper_clear_sky 860 → 924 (8),
/// crossing_pair 495 → 527 (6); the longer runs' medians 0.1–2 % lower, well inside their spread (2000 frames at
/// 256 × 256 2408 → 2370, runs 2030–2472 against 2229–2554; head_on 451 → 448, 446–463 against 379–461; 6 each).
/// First waits of 3 and 10 ms gained less (docs/accuracy.md, "The write-back thread's first passes sooner"). On a
/// 2-vCPU Intel Xeon and on a Zen 5 EPYC early passes had shown no gain.
#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
const WRITEBACK_FIRST_WAIT: std::time::Duration = std::time::Duration::from_millis(6);

/// The [`Writeback`] thread's wait after `wait`: twice it, at least a millisecond (a wait of 0 would spin) and
/// at most `period`.
#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
fn next_wait(wait: std::time::Duration, period: std::time::Duration) -> std::time::Duration {
    (wait * 2).max(std::time::Duration::from_millis(1)).min(period)
}

/// A thread of its own that starts the disk on the recording's files as they come: every [`WRITEBACK_PERIOD`]
/// (sooner at first, from [`WRITEBACK_FIRST_WAIT`] on), if files were written since its last pass, the files
/// written since then are handed to the disk (Linux), so that a checkpoint's sync, the last one's above all, finds
/// little left to write. The pass is made the way [`SyncWay::now`] picks: while the file system holds little to
/// write besides this recording's files, one `syncfs` of it (ten times a second at most after its first passes,
/// and only while files are being written), which costs the machine less than
/// asking for each file's write-back (one device request and one notification of the device each): 256 × 256 png16
/// into fresh ext4 directories on one thread of an AMD EPYC, 1616–1817 frames/s asking for each file as it was
/// written against 2046–2155 with the `syncfs` (interleaved rounds). Where other writers' data wait too (a build
/// just finished, another program writing), a `syncfs` would wait for all of it: the pass then asks for each of the
/// recording's files' write-back instead (`sync_file_range` with `SYNC_FILE_RANGE_WRITE`, not waited for).
///
/// The pass syncs through a descriptor of its own, so that a write-back error stays unreported on the recording's,
/// whose checkpoint reports it (see [`sync_written`]; Linux 5.8 and later). The pass also keeps the first error its
/// `syncfs` or `sync_file_range` returned, which the next checkpoint reports too: before 5.8 a `syncfs` returned
/// only the file system's and the device's errors, once, to whichever call came first, which may be the pass's.
struct Writeback {
    /// What the thread shares with the encoding tasks and the checkpoints.
    counts: Arc<WritebackCounts>,
    /// Set to stop the thread; the condition variable wakes it from its wait.
    stop: Arc<(Mutex<bool>, std::sync::Condvar)>,
    /// The thread, until it is stopped; `None` where none runs.
    thread: Option<std::thread::JoinHandle<()>>,
}

/// What a [`Writeback`] thread shares with the encoding tasks and the checkpoints.
#[derive(Debug, Default)]
struct WritebackCounts {
    /// The files written since the thread's last pass, listed by the encoding tasks while the thread runs.
    pending: Mutex<Vec<PathBuf>>,
    /// Whether a thread runs (and takes `pending`); without one nothing is listed.
    running: std::sync::atomic::AtomicBool,
    /// The bytes of the files written since the last sync began: this recording's share of the machine's data
    /// waiting to be written, for [`SyncWay::now`].
    unsynced_bytes: std::sync::atomic::AtomicU64,
    /// Passes made, by way: one `syncfs` ([`SyncWay::FileSystem`]) and file by file ([`SyncWay::EachFile`]).
    #[cfg_attr(not(test), allow(dead_code))]
    passes: [std::sync::atomic::AtomicU64; 2],
    /// The OS error number of the first pass that failed; 0 while none has.
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    failed: std::sync::atomic::AtomicI32,
    /// The file the first failed pass failed on (`None`: the file system's, a failed `syncfs`).
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    failed_on: Mutex<Option<PathBuf>>,
    /// Files held open ([`Held`]), and the most that may be.
    held: std::sync::atomic::AtomicUsize,
    max_held: std::sync::atomic::AtomicUsize,
    /// Every path a sync made durable file by file (files, then directories), in order, for tests.
    #[cfg(test)]
    synced_paths: Mutex<Vec<PathBuf>>,
    /// The most threads a sync file by file ran its files' syncs on, for tests.
    #[cfg(test)]
    most_sync_threads: std::sync::atomic::AtomicUsize,
    /// The way every sync takes where it is set (`1 +` the [`SyncWay`]'s index, for tests of each); 0: the way
    /// [`SyncWay::now`] picks for each.
    forced_way: std::sync::atomic::AtomicU8,
}

impl WritebackCounts {
    /// The way for a sync now, this recording's unsynced bytes being `ours` ([`SyncWay::now`], unless forced).
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn way(&self, ours: u64) -> SyncWay {
        match self.forced_way.load(std::sync::atomic::Ordering::Relaxed) {
            1 => SyncWay::FileSystem,
            2 => SyncWay::EachFile,
            _ => SyncWay::now(ours),
        }
    }

    /// Counts a file of `bytes` bytes written under `path`, and lists it for the next pass where a thread runs.
    fn wrote(&self, path: &Path, bytes: usize) {
        use std::sync::atomic::Ordering;
        self.unsynced_bytes.fetch_add(bytes as u64, Ordering::Relaxed);
        if self.running.load(Ordering::Relaxed) {
            self.pending.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push(path.to_path_buf());
        }
    }

    /// Takes the files listed since the last pass.
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn take_pending(&self) -> Vec<PathBuf> {
        std::mem::take(&mut *self.pending.lock().unwrap_or_else(std::sync::PoisonError::into_inner))
    }

    /// Keeps the first failed pass's OS error number `errno`, and the file it failed on (`None`: a `syncfs`).
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn pass_failed(&self, errno: Option<i32>, on: Option<&Path>) {
        use std::sync::atomic::Ordering;
        let errno = errno.unwrap_or(libc::EIO);
        // held across the number's change, so that a reader who sees the number and then takes the lock finds the file
        let mut failed_on = self.failed_on.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if self.failed.compare_exchange(0, errno, Ordering::Relaxed, Ordering::Relaxed).is_ok() {
            *failed_on = on.map(Path::to_path_buf);
        }
    }

    /// The first failed pass's error, as an error on the file it failed on, or on `dir` (a `syncfs`); `None` while
    /// no pass has failed.
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn pass_error(&self, dir: &Path) -> Option<RecordError> {
        let errno = self.failed.load(std::sync::atomic::Ordering::Relaxed);
        (errno != 0).then(|| {
            let on = self.failed_on.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone();
            io_err(on.as_deref().unwrap_or(dir), std::io::Error::from_raw_os_error(errno))
        })
    }

    /// Forgets `bytes` of the unsynced bytes: a sync that began when they were counted has made them durable.
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn synced(&self, bytes: u64) {
        use std::sync::atomic::Ordering;
        let _ =
            self.unsynced_bytes.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| Some(v.saturating_sub(bytes)));
    }
}

/// A file the recording wrote and has not yet made durable: its path and, where it may be held open, the file.
#[derive(Debug)]
struct Written {
    path: PathBuf,
    file: Option<Held>,
}

impl Written {
    /// A file known by its path only (it is opened again to be synced).
    fn by_path(path: PathBuf) -> Self {
        Self { path, file: None }
    }
}

/// A written file held open from its write until a checkpoint syncs it, so that the sync reports a write-back error
/// on it. The kernel keeps such an error with the file while it is in memory, and reports it to the next sync through
/// any descriptor; once the file is closed the kernel may drop it from memory, and its error with it, before the
/// checkpoint reopens it by path. (One `syncfs` through the directory held since the start reports it from the file
/// system's record instead.) The files held open are counted against a budget ([`descriptor_budget`]); past it a
/// file is closed as before and reopened to be synced.
#[derive(Debug)]
struct Held {
    file: std::fs::File,
    counts: Arc<WritebackCounts>,
}

/// Files held open ([`Held`]) by all the process's recordings (a dataset's, a window's and tests' may run at once).
static HELD_IN_PROCESS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

impl Held {
    /// `file`, held open if the recording's budget and the process's ([`descriptor_budget`]) allow; closed
    /// otherwise.
    fn keep(counts: &Arc<WritebackCounts>, file: std::fs::File) -> Option<Self> {
        use std::sync::atomic::Ordering;
        let mine = counts.held.fetch_add(1, Ordering::Relaxed) < counts.max_held.load(Ordering::Relaxed);
        let process = HELD_IN_PROCESS.fetch_add(1, Ordering::Relaxed) < descriptor_budget();
        if mine && process {
            Some(Self { file, counts: Arc::clone(counts) })
        } else {
            counts.held.fetch_sub(1, Ordering::Relaxed);
            HELD_IN_PROCESS.fetch_sub(1, Ordering::Relaxed);
            None
        }
    }
}

impl Drop for Held {
    fn drop(&mut self) {
        self.counts.held.fetch_sub(1, std::sync::atomic::Ordering::Relaxed);
        HELD_IN_PROCESS.fetch_sub(1, std::sync::atomic::Ordering::Relaxed);
    }
}

/// How many written files the process's recordings may hold open ([`Held`]): a quarter of its limit on open files,
/// at most 8192, after raising its soft limit toward the hard one (to 65 536 at most, once per process: a 256 × 256
/// recording with masks writes about 4000 files a second, and a file is held for up to a checkpoint's period and its
/// sync). None off Linux, where files are always reopened to be synced.
fn descriptor_budget() -> usize {
    #[cfg(target_os = "linux")]
    {
        static BUDGET: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
        *BUDGET.get_or_init(|| {
            let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
            // SAFETY: `limit` is a struct the call writes
            if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } != 0 {
                return 0;
            }
            let wanted = limit.rlim_max.min(1 << 16);
            if limit.rlim_cur < wanted {
                let raised = libc::rlimit { rlim_cur: wanted, rlim_max: limit.rlim_max };
                // SAFETY: `raised` is a struct the call reads
                if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &raised) } == 0 {
                    limit.rlim_cur = wanted;
                }
            }
            usize::try_from(limit.rlim_cur / 4).unwrap_or(usize::MAX).min(8192)
        })
    }
    #[cfg(not(target_os = "linux"))]
    0
}

/// The most bytes of other writers' data waiting to be written on the machine (the `Dirty` and `Writeback` of
/// `/proc/meminfo`, less this recording's unsynced bytes) at which a sync is one `syncfs` of the output's file
/// system; above it the recording's files are synced each on its own. A `syncfs` writes and waits for every dirty
/// file of the file system, other programs' too: after `dd` wrote 1.5 GB without a sync, paper_clear_sky recorded
/// at 61–68 frames/s with only `syncfs` against 548–898 with this choice (AMD EPYC, ext4 on a virtual disk of
/// about 1 GB/s, alternating runs), where with nothing else waiting the `syncfs` is the faster: syncing file by
/// file always, paper_vibration recorded at 1359–1556 frames/s against 1622–2036 (one device cache flush per file,
/// and the last checkpoint is waited for). At about 1 GB/s, 16 MiB of others' data is 16 ms of waiting at most.
/// Counts of the recording's own bytes err toward fewer (a pass and a checkpoint each forget what they began with),
/// so the choice errs toward file by file.
const FOREIGN_DIRTY_LIMIT_BYTES: u64 = 16 << 20;

/// How a sync makes the recording's files durable ([`sync_written`], and the [`Writeback`] thread's passes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SyncWay {
    /// One `syncfs` of the output's file system (Linux): one call and one journal commit for all the files, but it
    /// also waits for every other file of the file system waiting to be written.
    FileSystem,
    /// Each file on its own (`fdatasync`, one device cache flush each on ext4), then their directories: waits for
    /// nothing but the recording's own files.
    EachFile,
}

impl SyncWay {
    /// The way for a sync now, where this recording has written `ours` bytes since the last sync began: one `syncfs`
    /// while the machine holds at most [`FOREIGN_DIRTY_LIMIT_BYTES`] of others' data waiting to be written, file by
    /// file otherwise (and where `/proc/meminfo` cannot be read).
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    fn now(ours: u64) -> Self {
        let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
        Self::choose(meminfo.as_deref().and_then(waiting_bytes), ours)
    }

    /// [`SyncWay::now`] for `waiting` bytes of file data waiting to be written on the machine (`None`: unknown).
    fn choose(waiting: Option<u64>, ours: u64) -> Self {
        match waiting {
            Some(w) if w.saturating_sub(ours) <= FOREIGN_DIRTY_LIMIT_BYTES => Self::FileSystem,
            _ => Self::EachFile,
        }
    }
}

/// The bytes of file data waiting to be written that a `/proc/meminfo` text gives: its `Dirty` and `Writeback`
/// lines (kB), `None` where either is missing or unreadable.
fn waiting_bytes(meminfo: &str) -> Option<u64> {
    let field = |name: &str| -> Option<u64> {
        let line = meminfo.lines().find(|l| l.split(':').next() == Some(name))?;
        let mut words = line.split(':').nth(1)?.split_whitespace();
        let kb = words.next()?.parse::<u64>().ok()?;
        (words.next() == Some("kB")).then_some(kb.checked_mul(1024)?)
    };
    field("Dirty")?.checked_add(field("Writeback")?)
}

impl Writeback {
    /// Starts the thread for `dir`, passing `first` after its start, then after waits that double up to `period`
    /// ([`next_wait`]); where `dir` is `None` (the recording could not open its directory) or no thread can be
    /// started or no descriptor opened (or off Linux), none runs and the checkpoints' syncs write everything.
    fn start(dir: Option<&Path>, (first, period): (std::time::Duration, std::time::Duration)) -> Self {
        let counts = Arc::<WritebackCounts>::default();
        let stop = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
        let thread = dir.and_then(|dir| Self::spawn(dir, (first, period), Arc::clone(&counts), Arc::clone(&stop)));
        Self { counts, stop, thread }
    }

    #[cfg(target_os = "linux")]
    fn spawn(
        dir: &Path,
        (first, period): (std::time::Duration, std::time::Duration),
        counts: Arc<WritebackCounts>,
        stop: Arc<(Mutex<bool>, std::sync::Condvar)>,
    ) -> Option<std::thread::JoinHandle<()>> {
        use std::os::fd::AsRawFd;
        use std::sync::atomic::Ordering;
        let handle = std::fs::File::open(dir).ok()?;
        let running = Arc::clone(&counts);
        let work = move || {
            let (flag, wake) = &*stop;
            let mut stopped = flag.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            let mut wait = first.min(period);
            while !*stopped {
                stopped = wake.wait_timeout(stopped, wait).unwrap_or_else(std::sync::PoisonError::into_inner).0;
                wait = next_wait(wait, period);
                if *stopped {
                    continue;
                }
                let files = counts.take_pending();
                if files.is_empty() {
                    continue;
                }
                drop(stopped);
                let bytes = counts.unsynced_bytes.load(Ordering::Relaxed);
                let way = counts.way(bytes);
                let errno = || std::io::Error::last_os_error().raw_os_error();
                match way {
                    SyncWay::FileSystem => {
                        // SAFETY: `handle` is an open descriptor for the duration of the call
                        if unsafe { libc::syncfs(handle.as_raw_fd()) } != 0 {
                            counts.pass_failed(errno(), None);
                        }
                    }
                    SyncWay::EachFile => {
                        for f in &files {
                            // a file removed since (a failed run's frames) has nothing to write
                            let Ok(h) = std::fs::File::open(f) else { continue };
                            // SAFETY: `h` is an open descriptor for the duration of the call
                            if unsafe { libc::sync_file_range(h.as_raw_fd(), 0, 0, libc::SYNC_FILE_RANGE_WRITE) } != 0 {
                                counts.pass_failed(errno(), Some(f));
                            }
                        }
                    }
                }
                counts.synced(bytes);
                counts.passes[way as usize].fetch_add(1, Ordering::Relaxed);
                stopped = flag.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            }
        };
        running.running.store(true, Ordering::Relaxed);
        let thread = std::thread::Builder::new().name("irsim writeback".into()).spawn(work).ok();
        if thread.is_none() {
            running.running.store(false, Ordering::Relaxed);
        }
        thread
    }

    #[cfg(not(target_os = "linux"))]
    fn spawn(
        _: &Path,
        _: (std::time::Duration, std::time::Duration),
        _: Arc<WritebackCounts>,
        _: Arc<(Mutex<bool>, std::sync::Condvar)>,
    ) -> Option<std::thread::JoinHandle<()>> {
        None
    }

    /// Stops the thread and waits for it (a pass under way ends first).
    fn stop(&mut self) {
        let (flag, wake) = &*self.stop;
        *flag.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = true;
        wake.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        // nothing takes the list any more
        self.counts.running.store(false, std::sync::atomic::Ordering::Relaxed);
        drop(self.counts.take_pending());
    }
}

impl Drop for Writeback {
    fn drop(&mut self) {
        self.stop();
    }
}

/// [`write_atomic`] for a file that several processes may write at once with the same bytes (the shards of a
/// dataset, each putting its spec in place): the temporary file is this process's own, so a rename never takes
/// another's half-written file.
///
/// # Errors
/// The I/O error with the path.
pub fn write_shared(path: &Path, bytes: &[u8]) -> Result<(), RecordError> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    write_through(&tmp, path, bytes)
}

/// Makes `files` (written under `dir`), and `also`, durable, with their names: on Linux the way [`SyncWay::now`]
/// picks, either one `syncfs` of `dir`'s file system (its data and the links and renames that put the files in
/// place, in one journal commit) through `handle`, the directory opened when the recording began, or a sync of each
/// file, then of their directories and of `dir` (through `handle`); elsewhere always the latter.
///
/// A `syncfs` reports (Linux 5.8 and later) a write-back error that happened since the descriptor it is given was
/// opened (and that no call on it has reported yet): through one descriptor held for the whole recording, an error
/// on any file written since the start is reported, where a descriptor opened afresh for each checkpoint misses one that
/// another process's `syncfs` of the same file system saw first. A file's own sync reports an error on it that
/// no one has seen yet (Linux 4.16 and later), the [`Writeback`] thread's requests being no such call, while the
/// file stays in memory: files are synced through the descriptor they were written with where it was held open
/// ([`Held`]). `writeback` holds the first failed pass of the [`Writeback`] thread, read after the sync and
/// reported here as well, on the file it failed on.
///
/// # Errors
/// The I/O error with the path.
fn sync_written(
    dir: &Path,
    handle: Option<&std::fs::File>,
    (files, also): (&[Written], &[PathBuf]),
    writeback: &WritebackCounts,
) -> Result<(), RecordError> {
    let each = || {
        let files = files.iter().map(|w| (w.path.as_path(), w.file.as_ref().map(|h| &h.file)));
        files.chain(also.iter().map(|p| (p.as_path(), None)))
    };
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        let opened;
        let d = match handle {
            Some(h) => h,
            None => {
                opened = std::fs::File::open(dir).map_err(|e| io_err(dir, e))?;
                &opened
            }
        };
        let bytes = writeback.unsynced_bytes.load(std::sync::atomic::Ordering::Relaxed);
        match writeback.way(bytes) {
            SyncWay::FileSystem => {
                // SAFETY: `d` is an open descriptor for the duration of the call
                if unsafe { libc::syncfs(d.as_raw_fd()) } != 0 {
                    return Err(io_err(dir, std::io::Error::last_os_error()));
                }
            }
            SyncWay::EachFile => sync_each(each(), dir, writeback, |p| {
                if p == dir { d.sync_all() } else { std::fs::File::open(p).and_then(|h| h.sync_all()) }
            })?,
        }
        writeback.synced(bytes);
        // read after the sync, so that a pass that failed while it ran is reported too
        writeback.pass_error(dir).map_or(Ok(()), Err)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = handle;
        // directories cannot be opened for syncing on every platform (Windows): their syncs are best effort
        sync_each(each(), dir, writeback, |p| {
            if let Ok(h) = std::fs::File::open(p) {
                let _ = h.sync_all();
            }
            Ok(())
        })
    }
}

/// Syncs each of `files` (`fdatasync`: their bytes and their length), through the file where it is open, else
/// opened by its path, on up to [`SYNC_THREADS`] threads side by side; then, with `sync_dir`, which makes the names
/// in a directory durable, each of their directories and `dir`, once each. The error is that of one file that
/// failed (this thread's first, else the first of the lowest-numbered other thread that had one).
///
/// # Errors
/// The I/O error with the path.
fn sync_each<'a>(
    files: impl Iterator<Item = (&'a Path, Option<&'a std::fs::File>)>,
    dir: &'a Path,
    writeback: &WritebackCounts,
    sync_dir: impl Fn(&Path) -> std::io::Result<()>,
) -> Result<(), RecordError> {
    let log = |_p: &Path| {
        #[cfg(test)]
        writeback.synced_paths.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push(_p.to_path_buf());
    };
    let _ = writeback;
    let files: Vec<_> = files.collect();
    let sync = |(path, open): (&Path, Option<&std::fs::File>)| -> Result<(), RecordError> {
        let synced = match open {
            Some(f) => f.sync_data(),
            None => std::fs::File::open(path).and_then(|h| h.sync_data()),
        };
        synced.map_err(|e| io_err(path, e))?;
        log(path);
        Ok(())
    };
    // side by side, so that the disk's cache flushes, one per file, are shared (a flush asked for while another is
    // under way is served by the next one)
    let threads = (files.len() / SYNCS_PER_THREAD).clamp(1, SYNC_THREADS);
    // thread `t`'s files: every `threads`-th from the `t`-th; the first error among them
    let group = |t: usize| files.iter().skip(t).step_by(threads).find_map(|&f| sync(f).err());
    let first_error = std::thread::scope(|scope| {
        // the files of a thread that cannot be started are synced on this one
        let mut mine = vec![0];
        let mut parts = Vec::new();
        for t in 1..threads {
            match std::thread::Builder::new().name("irsim sync".into()).spawn_scoped(scope, move || group(t)) {
                Ok(handle) => parts.push(handle),
                Err(_) => mine.push(t),
            }
        }
        #[cfg(test)]
        writeback.most_sync_threads.fetch_max(parts.len() + 1, std::sync::atomic::Ordering::Relaxed);
        let mine = mine.into_iter().find_map(group);
        // every thread joined before an error is picked, so that none is left to the scope's end
        let theirs: Vec<_> = parts
            .into_iter()
            .map(|p| {
                p.join()
                    .unwrap_or_else(|_| Some(io_err(dir, "internal error: a sync's thread stopped (please report it)")))
            })
            .collect();
        std::iter::once(mine).chain(theirs).flatten().next()
    });
    if let Some(e) = first_error {
        return Err(e);
    }
    let mut dirs = std::collections::BTreeSet::from([dir]);
    dirs.extend(files.iter().filter_map(|(path, _)| path.parent()));
    for d in dirs {
        sync_dir(d).map_err(|e| io_err(d, e))?;
        log(d);
    }
    Ok(())
}

/// The most threads a sync file by file ([`sync_each`]) makes the files' syncs on, and the fewest files each. On ext4
/// each `fdatasync` asks the disk for a cache flush of its own; asked side by side, one flush serves those asked
/// while it ran. A C probe, 500 files of 48 kB once their bytes were on the disk: 48–55 ms one after another, 39–43
/// on 4 threads, 32–41 on 16. The recording after `dd` wrote 1.5 GB without a sync (so synced file by file), six
/// alternating runs, frames/s, one thread against up to four: paper_vibration 1222–1709 against 1607–1901,
/// paper_clear_sky 779–1056 against 546–1075 (medians 854 and 960); crossing_pair, whose last sync is a smaller
/// share of its run, 403–487 against 418–494 (three runs).
const SYNC_THREADS: usize = 4;
const SYNCS_PER_THREAD: usize = 8;

/// Name of the lock file a recording holds in its output directory.
pub const LOCK_FILE: &str = ".irsim.lock";

/// The output directory's lock: created with the directory's first recording step, removed when dropped.
#[derive(Debug)]
pub struct DirLock {
    path: PathBuf,
}

impl Drop for DirLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Takes `dir`'s lock: a file created exclusively, holding this process's id. A lock whose process no longer
/// runs (the recording was killed) is taken over.
fn lock_dir(dir: &Path) -> Result<DirLock, RecordError> {
    let path = dir.join(LOCK_FILE);
    for _ in 0..2 {
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(mut f) => {
                let _ = writeln!(f, "{}", std::process::id());
                return Ok(DirLock { path });
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let holder = std::fs::read_to_string(&path).unwrap_or_default().trim().to_owned();
                let alive = holder.parse::<u32>().map_or(true, |pid| {
                    !Path::new("/proc/self").exists() || Path::new(&format!("/proc/{pid}")).exists()
                });
                if alive {
                    let who = if holder.is_empty() { "unknown".to_owned() } else { holder };
                    return Err(RecordError::Locked(dir.display().to_string(), who));
                }
                let _ = std::fs::remove_file(&path);
            }
            Err(e) => return Err(io_err(&path, e)),
        }
    }
    Err(RecordError::Locked(dir.display().to_string(), "unknown".into()))
}

/// Whether `name`, in an output directory, is a temporary a recording makes and renames (left behind by one that
/// was killed): a subdirectory being made ([`make_subdirectory`]), a label, MOT or manifest file being written, or
/// one of the hidden copies the labels and MOT lines are appended to ([`ShadowedText`]).
fn is_leftover(name: &str) -> bool {
    let made = ["frames", "masks"].iter().any(|sub| {
        name.strip_prefix('.')
            .and_then(|n| n.strip_prefix(sub))
            .and_then(|n| n.strip_prefix('.'))
            .and_then(|n| n.strip_suffix(".tmp"))
            .is_some_and(|n| n.split('.').all(|part| !part.is_empty() && part.bytes().all(|b| b.is_ascii_digit())))
    });
    made || ["labels.jsonl.tmp", "gt_mot.txt.tmp", "manifest.json.tmp"].contains(&name)
        || TEXT_FILES.iter().any(|text| (0..2).any(|slot| shadow_name(text, slot) == name))
}

/// Prepares `dir`: creates it and takes its lock, or refuses if another recording holds the lock, or if the
/// directory holds anything unless `force`, in which case it removes the outputs of an earlier run (frames,
/// masks, labels, MOT file, manifest, and the temporaries of one that was killed) and nothing else. Keep the
/// returned lock for the whole recording.
///
/// # Errors
/// [`RecordError::NotEmpty`], [`RecordError::NotADirectory`], [`RecordError::Locked`] or an I/O error.
pub fn prepare_dir(dir: &Path, force: bool) -> Result<DirLock, RecordError> {
    if dir.exists() && !dir.is_dir() {
        return Err(RecordError::NotADirectory(dir.display().to_string()));
    }
    std::fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
    let lock = lock_dir(dir)?;
    {
        let mut entries = std::fs::read_dir(dir)
            .map_err(|e| io_err(dir, e))?
            .filter(|e| e.as_ref().map_or(true, |e| e.file_name() != LOCK_FILE));
        if entries.next().is_some() {
            if !force {
                return Err(RecordError::NotEmpty(dir.display().to_string()));
            }
            for sub in ["frames", "masks"] {
                let p = dir.join(sub);
                if p.exists() {
                    std::fs::remove_dir_all(&p).map_err(|e| io_err(&p, e))?;
                }
            }
            for f in ["labels.jsonl", "gt_mot.txt", "manifest.json"] {
                let p = dir.join(f);
                if p.exists() {
                    std::fs::remove_file(&p).map_err(|e| io_err(&p, e))?;
                }
            }
            for entry in std::fs::read_dir(dir).map_err(|e| io_err(dir, e))? {
                let entry = entry.map_err(|e| io_err(dir, e))?;
                if !entry.file_name().to_str().is_some_and(is_leftover) {
                    continue;
                }
                let p = entry.path();
                // a link is removed, not followed
                let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
                let removed = if is_dir { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
                removed.map_err(|e| io_err(&p, e))?;
            }
        }
    }
    spread_subdirectories(dir);
    make_subdirectory(dir, "frames")?;
    Ok(lock)
}

/// Makes `dir/name` unless it is there: made under a name of its own and renamed, so that where `dir` is the top
/// of a hierarchy ([`spread_subdirectories`]) the block group ext4 chooses for it, which starts from a hash of the
/// name, differs from one recording to the next (under the same name, each recording's frames went to the group
/// the last one's were deleted from).
fn make_subdirectory(dir: &Path, name: &str) -> Result<(), RecordError> {
    let path = dir.join(name);
    if path.is_dir() {
        return Ok(());
    }
    let fresh = dir.join(fresh_name(name));
    if std::fs::create_dir(&fresh).is_ok() && std::fs::rename(&fresh, &path).is_err() {
        let _ = std::fs::remove_dir(&fresh);
    }
    std::fs::create_dir_all(&path).map_err(|e| io_err(&path, e))
}

/// Marks `dir` as the top of a directory hierarchy (ext4's `T` attribute, `chattr +T`; Linux), so that the file system
/// places the subdirectories made next (`frames`, `masks`) in block groups of their own with room to spare, not beside
/// `dir`'s parent. Where files were deleted near the parent in the last minutes (an earlier recording removed, or
/// replaced with `--force`), the ext4 of the machine measured looked past every recently deleted inode there for each
/// file it created (`recently_deleted` in `perf`; the kernel makes that check on a file system without a journal, so on
/// others the gain may be smaller): 2000 frames of 256 × 256 recorded into a new subdirectory of `/tmp`, each run after
/// the last one's was deleted, ran at 1405–2353 frames/s placed beside the parent and at 2467–3800 spread (and `irsim
/// bench`'s recording case, which deletes its output, at 0.18–0.22 of the rate without disk writes run after run
/// against 0.71–0.80; an AMD EPYC, interleaved rounds). Best effort: a file system without the attribute, or a
/// directory this user does not own, keeps its placement.
fn spread_subdirectories(dir: &Path) {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        /// `FS_TOPDIR_FL` of `linux/fs.h`.
        const TOPDIR: libc::c_int = 0x0002_0000;
        let Ok(handle) = std::fs::File::open(dir) else { return };
        let mut flags: libc::c_int = 0;
        // SAFETY: `handle` is an open descriptor and `flags` an int the call writes (the kernel's
        // FS_IOC_GETFLAGS takes a pointer to int)
        if unsafe { libc::ioctl(handle.as_raw_fd(), libc::FS_IOC_GETFLAGS, &mut flags) } != 0 || flags & TOPDIR != 0 {
            return;
        }
        flags |= TOPDIR;
        // SAFETY: as above; the call reads `flags`
        unsafe { libc::ioctl(handle.as_raw_fd(), libc::FS_IOC_SETFLAGS, &flags) };
    }
    #[cfg(not(target_os = "linux"))]
    let _ = dir;
}

/// One frame for an encoding task.
struct Job {
    index: u64,
    frame: Frame,
    mask: Option<Vec<u8>>,
    labels: FrameLabels,
}

/// A worker's answer: the frame's buffer comes back for reuse, with the files it wrote.
struct Done {
    index: u64,
    result: Result<(), RecordError>,
    labels: FrameLabels,
    frame: Frame,
    files: Vec<Written>,
}

/// What every encoding task of a recording shares.
struct TaskSpec {
    dir: PathBuf,
    format: FrameFormat,
    png: PngCompression,
    max_level: u16,
    /// The [`Writeback`] thread's counts: each file written is counted there, and listed for its next pass.
    writeback: Arc<WritebackCounts>,
    /// Whether frames are written as unnamed files and linked ([`write_unnamed_pausing`]); cleared where they cannot
    /// be.
    unnamed: std::sync::atomic::AtomicBool,
}

thread_local! {
    /// The encoder's buffers of this thread, kept from frame to frame (allocation only while they grow).
    static SCRATCH: std::cell::RefCell<(EncodeScratch, Vec<u8>)> = std::cell::RefCell::default();
}

/// Frames waiting to be encoded and written, shared by the recorder and the threads that encode them.
pub struct EncodeQueue {
    spec: TaskSpec,
    jobs: Mutex<VecDeque<Job>>,
    done: Sender<Done>,
}

impl EncodeQueue {
    /// Encodes and writes the oldest waiting frame on this thread, pausing for the pool's jobs (where this
    /// thread is in a pool) every [`crate::imaging::png16::PAUSE_BYTES`]; false if no frame waits.
    pub fn run_one(&self) -> bool {
        self.run_next(true)
    }

    /// The oldest waiting frame, encoded with pauses for the pool's jobs or without; false if none waits.
    fn run_next(&self, pausing: bool) -> bool {
        let job = self.jobs.lock().unwrap_or_else(std::sync::PoisonError::into_inner).pop_front();
        let Some(job) = job else { return false };
        run_task(&self.spec, job, &self.done, pausing);
        true
    }

    /// Whether the format's encoder pauses for the pool's jobs as it goes (16-bit PNG at `fast`); the others
    /// would hold a waiting worker away from the frame's stages for a whole frame.
    fn pauses(&self) -> bool {
        encoder_pauses(self.spec.format, self.spec.png)
    }

    fn push(&self, job: Job) {
        self.jobs.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push_back(job);
    }
}

/// One frame's task: encodes it and its mask, writes them, and sends them back with their fate. A panic is
/// caught and sent back as the frame's error (a task of the pool must not unwind into it).
fn run_task(spec: &TaskSpec, job: Job, tx: &Sender<Done>, pausing: bool) {
    let index = job.index;
    let work = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        SCRATCH.with(|cell| match cell.try_borrow_mut() {
            Ok(mut scratch) => {
                let (scratch, bytes) = &mut *scratch;
                write_job(spec, &job, scratch, bytes, pausing)
            }
            // a frame encoded inside another's pause (a pool's job that records): fresh buffers, never a panic
            Err(_) => write_job(spec, &job, &mut EncodeScratch::default(), &mut Vec::new(), pausing),
        })
    }));
    let done = match work {
        Ok((result, files)) => Done { index, result, labels: job.labels, frame: job.frame, files },
        Err(panic) => {
            let what = panic_text(panic.as_ref());
            let error = RecordError::Io {
                path: spec.dir.display().to_string(),
                message: format!("internal error encoding frame {index}: {what} (please report it)"),
            };
            Done { index, result: Err(error), labels: job.labels, frame: job.frame, files: Vec::new() }
        }
    };
    // the recorder is gone only if its thread panicked; nothing is left to tell then
    let _ = tx.send(done);
}

/// The message a caught panic carries (its `&str` or `String` payload), or nothing.
pub(crate) fn panic_text(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_default()
}

/// Encodes and writes a job's frame and mask; returns the outcome and the files written.
fn write_job(
    spec: &TaskSpec,
    job: &Job,
    scratch: &mut EncodeScratch,
    bytes: &mut Vec<u8>,
    pausing: bool,
) -> (Result<(), RecordError>, Vec<Written>) {
    // each file appears under its name complete (linked or renamed into place when whole); it is made durable
    // with the others at the next checkpoint, before the labels that list it
    // the encoder and the writes look for the pool's jobs as they go (between system calls, and every
    // PAUSE_BYTES written: a frame's writes held the thread ~40 µs on ext4, its stages meanwhile on one core)
    let mut pause = || {
        if pausing {
            rayon::yield_now();
        }
    };
    let frame_path = spec.dir.join("frames").join(format!("{:06}.{}", job.index, spec.format.extension()));
    encode_into_pausing(&job.frame, (spec.format, spec.max_level, spec.png), scratch, bytes, &mut pause);
    // only files that were written go on the list to sync, each still open where it may be ([`Held`])
    let mut files = Vec::new();
    let mut unsynced = |path: PathBuf, bytes: &[u8]| {
        let file = write_whole_pausing(&path, bytes, &mut pause, &spec.unnamed)?;
        spec.writeback.wrote(&path, bytes.len());
        files.push(Written { file: file.and_then(|f| Held::keep(&spec.writeback, f)), path });
        Ok(())
    };
    let mut result = unsynced(frame_path, bytes);
    if let (Ok(()), Some(mask)) = (&result, &job.mask) {
        bytes.clear();
        crate::imaging::frame::write_gray8_png(mask, job.frame.width(), job.frame.height(), &mut *bytes)
            .expect("a mask is the frame's size");
        result = unsynced(spec.dir.join("masks").join(format!("{:06}.png", job.index)), bytes);
    }
    (result, files)
}

/// Whether `format` at `png` is written by an encoder that calls its `pause` as it goes (16-bit PNG at `fast`).
fn encoder_pauses(format: FrameFormat, png: PngCompression) -> bool {
    format == FrameFormat::Png16 && png == PngCompression::Fast
}

/// Encodes `frame` in `format` into bytes.
pub fn encode(frame: &Frame, format: FrameFormat, max_level: u16, png: PngCompression) -> Vec<u8> {
    let mut bytes = Vec::new();
    encode_into(frame, format, max_level, png, &mut EncodeScratch::default(), &mut bytes);
    bytes
}

/// An encoder thread's buffers, kept from frame to frame.
#[derive(Debug, Default)]
pub struct EncodeScratch {
    samples: Vec<u16>,
    png16: Png16Encoder,
}

/// [`encode`] into `bytes` (replacing its contents), with `scratch` kept by the caller from frame to frame.
pub fn encode_into(
    frame: &Frame,
    format: FrameFormat,
    max_level: u16,
    png: PngCompression,
    scratch: &mut EncodeScratch,
    bytes: &mut Vec<u8>,
) {
    encode_into_pausing(frame, (format, max_level, png), scratch, bytes, &mut || {});
}

/// [`encode_into`], the encoder calling `pause` as it goes where it does ([`encoder_pauses`]).
fn encode_into_pausing(
    frame: &Frame,
    (format, max_level, png): (FrameFormat, u16, PngCompression),
    scratch: &mut EncodeScratch,
    bytes: &mut Vec<u8>,
    pause: &mut dyn FnMut(),
) {
    bytes.clear();
    match format {
        FrameFormat::Png16 if encoder_pauses(format, png) => {
            scratch.png16.encode_pausing(frame.pixels(), frame.width(), frame.height(), max_level, bytes, pause);
        }
        FrameFormat::Png16 => {
            frame.png16_samples(max_level, &mut scratch.samples);
            frame.write_png16_samples(&scratch.samples, png, &mut *bytes).expect("writing to memory");
        }
        FrameFormat::Png8 => frame.write_png8(f32::from(max_level), &mut *bytes).expect("writing to memory"),
        // the AGC has already mapped the frame to 0–255
        FrameFormat::Png8Agc => frame.write_png8(255.0, &mut *bytes).expect("writing to memory"),
        FrameFormat::Npy => write_npy_f32(frame, bytes),
    }
}

/// A little-endian float32 `.npy` (format 1.0) of shape (height, width).
fn write_npy_f32(frame: &Frame, out: &mut Vec<u8>) {
    let mut header =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}", frame.height(), frame.width());
    // magic (6) + version (2) + header length (2) + header, padded with spaces to a multiple of 64, ending in \n
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in frame.pixels() {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Where a recording stands, as written to the manifest.
#[derive(Debug, Clone, Serialize)]
pub struct Progress {
    /// `running`, `complete`, `interrupted` or `failed`.
    pub status: String,
    /// Frames asked for.
    pub frames_requested: u64,
    /// Frames written, with their labels: frames 0 … n−1.
    pub frames_written: u64,
    /// The error that stopped the run, if any.
    pub error: Option<String>,
}

/// The recorder: encoding tasks, ordered commit, checkpoints.
pub struct Recorder {
    dir: PathBuf,
    /// The output directory, open for the whole recording: the checkpoints' syncs go through it
    /// ([`sync_written`]); `None` where a directory cannot be opened as a file.
    dir_handle: Option<Arc<std::fs::File>>,
    format: FrameFormat,
    masks: bool,
    /// The frames waiting to be encoded.
    queue: Arc<EncodeQueue>,
    done: Receiver<Done>,
    /// At most this many frames are handed out and not yet back.
    max_in_flight: u64,
    /// Frames back from their tasks (committed or waiting in `pending`).
    returned: u64,
    pending: BTreeMap<u64, FrameLabels>,
    committed: u64,
    sent: u64,
    /// The committed frames' label lines and MOT lines.
    labels: ShadowedText,
    mot: ShadowedText,
    /// Frames whose labels and MOT lines the files on disk hold (the last successful checkpoint).
    on_disk: u64,
    /// Whether the label and MOT files have been written at all.
    texts_written: bool,
    last_checkpoint: Instant,
    error: Option<RecordError>,
    manifest: serde_json::Value,
    frames_requested: u64,
    agc: Option<(Agc, u32)>,
    /// Files the tasks wrote since the last checkpoint's sync.
    unsynced: Vec<Written>,
    /// Frame buffers the tasks are done with.
    spare: Vec<Frame>,
    /// The checkpoint being written in the background.
    writing: Option<Writing>,
    writeback: Writeback,
}

/// A checkpoint being written by a thread of its own: the frames it covers, and (should the thread not report)
/// the files it was to make durable.
struct Writing {
    handle: std::thread::JoinHandle<CheckpointOutcome>,
    frames: u64,
    files: Vec<PathBuf>,
}

/// How far a failed checkpoint got.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reached {
    /// The files on disk are as before (the sync or the labels' write failed).
    Nothing,
    /// The labels list the checkpoint's frames; the MOT file is behind them.
    Labels,
    /// The labels and the MOT file; only the manifest failed.
    Texts,
}

/// How a checkpoint went, and the files it was to make durable and did not (they go back to the recorder's list,
/// for the next checkpoint).
struct CheckpointOutcome {
    result: Result<(), (Reached, RecordError)>,
    unsynced: Vec<Written>,
    /// Per text, how its append went.
    texts: Option<[TextOutcome; 2]>,
}

/// How a checkpoint's append to a [`ShadowedText`] went: its shadow and the frames it was to hold, whether the
/// lines were appended and synced, and whether the shadow was put in place.
type TextOutcome = ((usize, u64), bool, bool);

/// A text a recording adds lines to at each committed frame (the labels, the MOT lines) and puts in place at each
/// checkpoint without writing it whole: two hidden files in the output directory (its "shadows", `.labels.jsonl.0`
/// and `.labels.jsonl.1`) take turns. A checkpoint appends the lines the shadow not in place lacks (those since the
/// checkpoint before last) to it, after cutting it back to the lines it is known to hold (a failed append's bytes go),
/// and once the frames and it are synced links it under a temporary name and renames that over the file's name, then
/// syncs once more, so that no crash finds the name still on the file the next checkpoint appends to. The lines count
/// as the shadow's only once synced (a failed sync's are appended again). The file under the name is never written
/// while it is there (a shadow that is the file in place, `same_file`, Unix, is refused; so is one shorter than what
/// it holds), so it is always a whole, synced text, as when the text
/// was written whole to a temporary file and renamed; where the file system has no hard links, the shadow is copied
/// (and synced) instead. Each line is written twice in all, where writing the text whole at each checkpoint (once a
/// second) wrote each of a recording's n lines n / (2 · frames a second) times on average: at 20 000 frames of
/// 256 × 256 each checkpoint near the end wrote the whole 12.3 MB of labels, and a recording of 10⁶ frames would have rewritten 600 MB every second and
/// held them in memory twice. Only the lines not yet in both shadows stay in memory. The last checkpoint removes the
/// shadows' names (the file in place keeps its own).
#[derive(Debug)]
struct ShadowedText {
    /// The file's name in the output directory (`labels.jsonl`, `gt_mot.txt`).
    name: &'static str,
    /// The lines of the committed frames from `first` on; those before are in both shadows.
    text: String,
    first: u64,
    /// Where each committed frame's lines end, bytes from the start of the text.
    ends: Vec<u64>,
    /// The frames whose lines each shadow holds (it may hold more bytes: a failed append's, cut before the next).
    held: [u64; 2],
    /// The shadow in place under `name`.
    shown: Option<usize>,
}

impl ShadowedText {
    fn new(name: &'static str) -> Self {
        Self { name, text: String::new(), first: 0, ends: Vec::new(), held: [0, 0], shown: None }
    }

    /// Bytes of the first `frames` committed frames' lines.
    fn end(&self, frames: u64) -> u64 {
        frames.checked_sub(1).map_or(0, |i| self.ends[i as usize])
    }

    /// Adds the next committed frame's lines, written by `lines`.
    fn push(&mut self, lines: impl FnOnce(&mut String)) {
        lines(&mut self.text);
        self.ends.push(self.end(self.first) + self.text.len() as u64);
    }

    /// The path of shadow `slot` in `dir`.
    fn shadow(&self, dir: &Path, slot: usize) -> PathBuf {
        dir.join(shadow_name(self.name, slot))
    }

    /// What a checkpoint of the first `frames` committed frames appends, to the shadow not in place.
    fn append_for(&self, dir: &Path, frames: u64) -> Append {
        let slot = self.shown.map_or(0, |s| 1 - s);
        let (keep, base) = (self.end(self.held[slot]), self.end(self.first));
        let bytes = self.text[(keep - base) as usize..(self.end(frames) - base) as usize].to_owned();
        Append { slot, frames, shadow: self.shadow(dir, slot), keep, bytes, name: dir.join(self.name) }
    }

    /// Files how a checkpoint's append went: shadow `slot` holds the first `frames` frames (`appended`) and is in
    /// place (`shown`). The lines both shadows hold are dropped from memory.
    fn applied(&mut self, (slot, frames): (usize, u64), appended: bool, shown: bool) {
        if appended {
            self.held[slot] = frames;
        }
        if shown {
            self.shown = Some(slot);
        }
        let first = self.held[0].min(self.held[1]);
        if first > self.first {
            let cut = (self.end(first) - self.end(self.first)) as usize;
            self.text.drain(..cut);
            self.first = first;
        }
    }

    /// Forgets the frames after the first `n`; a shadow holding more is cut back at its next append.
    fn truncate(&mut self, n: u64) {
        if n >= self.ends.len() as u64 {
            return;
        }
        if n >= self.first {
            self.text.truncate((self.end(n) - self.end(self.first)) as usize);
        } else {
            self.text.clear();
            self.first = n;
        }
        self.ends.truncate(n as usize);
        self.held = self.held.map(|k| k.min(n));
    }
}

/// The name of a [`ShadowedText`]'s shadow `slot` (0 or 1) of the file `name`: `.labels.jsonl.0`.
fn shadow_name(name: &str, slot: usize) -> String {
    format!(".{name}.{slot}")
}

/// The files whose lines [`ShadowedText`]s hold.
const TEXT_FILES: [&str; 2] = ["labels.jsonl", "gt_mot.txt"];

/// Whether `a` and `b` name the same file (Unix; elsewhere, false).
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        matches!((std::fs::metadata(a), std::fs::metadata(b)), (Ok(x), Ok(y)) if x.dev() == y.dev() && x.ino() == y.ino())
    }
    #[cfg(not(unix))]
    {
        let _ = (a, b);
        false
    }
}

/// One checkpoint's append to a [`ShadowedText`]'s shadow, and how it is put in place.
#[derive(Debug)]
struct Append {
    slot: usize,
    /// The committed frames the shadow holds after it.
    frames: u64,
    shadow: PathBuf,
    /// The bytes the shadow is cut back to first (the lines it holds).
    keep: u64,
    bytes: String,
    /// The file's path under its own name.
    name: PathBuf,
}

impl Append {
    /// Cuts the shadow back to what it holds and appends the new lines (not synced: the checkpoint's sync does).
    fn write(&self) -> Result<(), RecordError> {
        use std::io::{Seek, SeekFrom};
        let err = |e| io_err(&self.shadow, e);
        // never the file in place (a checkpoint whose thread did not report may have put this shadow there)
        if same_file(&self.shadow, &self.name) {
            return Err(err(std::io::Error::other("the hidden copy is the file in place; not written")));
        }
        let mut f =
            std::fs::OpenOptions::new().write(true).create(true).truncate(false).open(&self.shadow).map_err(err)?;
        // a shadow shorter than the lines it holds was cut by someone else: not padded and put in place
        if f.metadata().map_err(err)?.len() < self.keep {
            return Err(err(std::io::Error::other(format!("shorter than the {} bytes written to it", self.keep))));
        }
        f.set_len(self.keep).map_err(err)?;
        f.seek(SeekFrom::Start(self.keep)).map_err(err)?;
        f.write_all(self.bytes.as_bytes()).map_err(err)
    }

    /// Puts the shadow in place under the file's name: linked under the temporary name, which is renamed over the
    /// name (where the file system has no hard links, a copy, synced before the rename).
    fn show(&self) -> Result<(), RecordError> {
        let temp = temporary_of(&self.name);
        let _ = std::fs::remove_file(&temp);
        if std::fs::hard_link(&self.shadow, &temp).is_err() {
            std::fs::copy(&self.shadow, &temp)
                .and_then(|_| std::fs::OpenOptions::new().write(true).open(&temp)?.sync_all())
                .map_err(|e| io_err(&temp, e))?;
        }
        std::fs::rename(&temp, &self.name).map_err(|e| {
            let _ = std::fs::remove_file(&temp);
            io_err(&self.name, e)
        })
    }
}

/// What one checkpoint writes (a snapshot of the recorder's state, so that a thread of its own can write it).
struct CheckpointJob {
    dir: PathBuf,
    dir_handle: Option<Arc<std::fs::File>>,
    /// The [`Writeback`] thread's counts, for its first error ([`sync_written`]).
    writeback: Arc<WritebackCounts>,
    /// The frames committed: those the labels list and the manifest counts.
    frames: u64,
    /// Files to make durable before the labels that list them.
    unsynced: Vec<Written>,
    /// The labels' and the MOT lines' appends, where the files on disk do not hold them yet.
    texts: Option<[Append; 2]>,
    manifest: String,
    /// The recording's last checkpoint: no write-back pass follows it, so it makes its files' names durable too;
    /// it removes these (the texts' shadows) first, when it has put everything in place.
    last: bool,
    shadows: Vec<PathBuf>,
    /// How the texts' appends went: appended, put in place.
    done: [(bool, bool); 2],
}

impl CheckpointJob {
    /// Appends the texts' new lines to their shadows and writes the manifest under its temporary name, syncs them
    /// with the frames written since the last checkpoint, then puts the labels, the MOT file and the manifest in
    /// place, in that order (see [`ShadowedText`]).
    fn write(mut self) -> CheckpointOutcome {
        // a panic here still reports how far the texts got, so that the recorder never takes a shadow in place
        // for the one not in place
        let result =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.write_files())).unwrap_or_else(|p| {
                let what = panic_text(p.as_ref());
                let reached = match self.done.map(|d| d.1) {
                    [true, true] => Reached::Texts,
                    [true, false] => Reached::Labels,
                    _ => Reached::Nothing,
                };
                Err((
                    reached,
                    RecordError::Io {
                        path: self.dir.display().to_string(),
                        message: format!("checkpoint failed: {what}"),
                    },
                ))
            });
        let texts =
            self.texts.as_ref().map(|t| [0, 1].map(|i| ((t[i].slot, t[i].frames), self.done[i].0, self.done[i].1)));
        CheckpointOutcome { result, unsynced: self.unsynced, texts }
    }

    fn write_files(&mut self) -> Result<(), (Reached, RecordError)> {
        let manifest = self.dir.join("manifest.json");
        let manifest_temp = temporary_of(&manifest);
        let mut early = false;
        if let Some(texts) = &self.texts {
            for append in texts {
                append.write().map_err(|e| (Reached::Nothing, e))?;
            }
            // the manifest too, so that the same sync makes it durable (where it cannot be written now, a full
            // disk, it is written after the texts are in place, as it can)
            early = std::fs::write(&manifest_temp, self.manifest.as_bytes()).is_ok();
            // a checkpoint that stops before the manifest's rename takes its temporary away
            let stop = |reached, e| {
                if early {
                    let _ = std::fs::remove_file(&manifest_temp);
                }
                (reached, e)
            };
            let mut also: Vec<PathBuf> = texts.iter().map(|a| a.shadow.clone()).collect();
            if early {
                also.push(manifest_temp.clone());
            }
            let synced = sync_written(&self.dir, self.dir_handle.as_deref(), (&self.unsynced, &also), &self.writeback);
            synced.map_err(|e| stop(Reached::Nothing, e))?;
            self.unsynced.clear();
            // the lines are the shadows' only once synced: a failed sync's are written again by the next checkpoint
            self.done = self.done.map(|(_, shown)| (true, shown));
            // labels first: a failure between the two leaves the MOT file behind, never ahead
            for (i, (append, reached)) in texts.iter().zip([Reached::Nothing, Reached::Labels]).enumerate() {
                append.show().map_err(|e| stop(reached, e))?;
                self.done[i].1 = true;
            }
            // the names made durable now: the next checkpoint appends to the shadows they were taken from, which
            // a crash must not find still under the names
            if !self.last {
                sync_written(&self.dir, self.dir_handle.as_deref(), (&[], &[]), &self.writeback)
                    .map_err(|e| (Reached::Texts, e))?;
            }
        } else if !self.unsynced.is_empty() {
            sync_written(&self.dir, self.dir_handle.as_deref(), (&self.unsynced, &[]), &self.writeback)
                .map_err(|e| (Reached::Nothing, e))?;
            self.unsynced.clear();
        }
        let placed = if early {
            std::fs::rename(&manifest_temp, &manifest).map_err(|e| {
                let _ = std::fs::remove_file(&manifest_temp);
                io_err(&manifest, e)
            })
        } else {
            write_atomic(&manifest, self.manifest.as_bytes())
        };
        if let Err(e) = placed {
            // a full disk may still take the manifest in place of the old one (same size or so)
            std::fs::write(&manifest, self.manifest.as_bytes()).map_err(|_| (Reached::Texts, e))?;
        }
        if self.last {
            // everything is in place: the shadows' names go (the files in place keep theirs), and one more sync
            // makes the names durable (the frames' and texts' bytes are on the disk already)
            for p in &self.shadows {
                if let Err(e) = std::fs::remove_file(p)
                    && e.kind() != std::io::ErrorKind::NotFound
                {
                    return Err((Reached::Texts, io_err(p, e)));
                }
            }
            sync_written(&self.dir, self.dir_handle.as_deref(), (&[], &[]), &self.writeback)
                .map_err(|e| (Reached::Texts, e))?;
        }
        Ok(())
    }
}

impl Recorder {
    /// A recorder writing into the prepared directory `dir`, its frames encoded by the threads of rayon's pool (see the
    /// module's docs), at most `2 · threads` frames out at once. `manifest` is the run's description; the recorder adds
    /// `status`, `frames_requested`, `frames_written` and `error`.
    pub fn new(
        dir: &Path,
        (format, png): (FrameFormat, PngCompression),
        masks: bool,
        max_level: u16,
        threads: usize,
        manifest: serde_json::Value,
        frames_requested: u64,
    ) -> Result<Self, RecordError> {
        if masks {
            make_subdirectory(dir, "masks")?;
        }
        let (done_tx, done_rx) = channel::<Done>();
        let dir_handle = std::fs::File::open(dir).ok().map(Arc::new);
        let writeback = Writeback::start(dir_handle.is_some().then_some(dir), (WRITEBACK_FIRST_WAIT, WRITEBACK_PERIOD));
        writeback.counts.max_held.store(descriptor_budget(), std::sync::atomic::Ordering::Relaxed);
        let spec = TaskSpec {
            dir: dir.to_path_buf(),
            format,
            png,
            max_level,
            writeback: Arc::clone(&writeback.counts),
            unnamed: std::sync::atomic::AtomicBool::new(unnamed_files_fit(&dir.join("frames"))),
        };
        let queue = Arc::new(EncodeQueue { spec, jobs: Mutex::new(VecDeque::new()), done: done_tx });
        let mut rec = Self {
            dir: dir.to_path_buf(),
            dir_handle,
            format,
            masks,
            queue,
            done: done_rx,
            max_in_flight: 2 * threads.max(1) as u64,
            returned: 0,
            pending: BTreeMap::new(),
            committed: 0,
            sent: 0,
            labels: ShadowedText::new(TEXT_FILES[0]),
            mot: ShadowedText::new(TEXT_FILES[1]),
            on_disk: 0,
            texts_written: false,
            last_checkpoint: Instant::now(),
            error: None,
            manifest,
            frames_requested,
            agc: (format == FrameFormat::Png8Agc).then(|| (Agc::new(AgcSpec::default()), u32::from(max_level))),
            unsynced: Vec::new(),
            spare: Vec::new(),
            writing: None,
            writeback,
        };
        rec.checkpoint("running")?;
        Ok(rec)
    }

    /// Frames committed so far.
    pub fn frames_written(&self) -> u64 {
        self.committed
    }

    /// Marks the run failed with `message` (the frames so far are kept, with their labels).
    pub fn fail(&mut self, message: String) {
        self.error.get_or_insert(RecordError::Io { path: self.dir.display().to_string(), message });
    }

    /// A frame buffer the tasks have finished with, for the next frame.
    pub fn take_spare(&mut self) -> Option<Frame> {
        self.spare.pop()
    }

    /// Frames handed to the recorder so far.
    pub fn frames_sent(&self) -> u64 {
        self.sent
    }

    /// The first write error, if one happened; the caller should stop sending frames.
    pub fn failed(&self) -> bool {
        self.error.is_some()
    }

    /// Queues a frame to be encoded; while more than twice `threads` frames are out, encodes waiting frames on
    /// this thread or waits for one to come back.
    pub fn push(&mut self, mut frame: Frame, mask: Option<Vec<u8>>, labels: FrameLabels) {
        if self.error.is_some() {
            return;
        }
        // the AGC's state runs over the frames in order, so it is applied here, not in the tasks
        if let Some((agc, max_level)) = &mut self.agc {
            agc.apply(frame.pixels_mut(), *max_level);
        }
        let job = Job { index: self.sent, frame, mask: if self.masks { mask } else { None }, labels };
        self.sent += 1;
        self.queue.push(job);
        if rayon::current_thread_index().is_none() || !self.queue.pauses() {
            // outside a pool no waiting worker looks at the queue, and a format that does not pause is not
            // waiting workers' work: a task of the pool takes the frame, without pausing (a pause there could
            // only start another frame's task inside it)
            let queue = Arc::clone(&self.queue);
            rayon::spawn(move || {
                queue.run_next(false);
            });
        }
        self.collect();
        while self.sent - self.returned > self.max_in_flight {
            self.wait_for_one();
        }
        if self.last_checkpoint.elapsed().as_secs_f64() >= 1.0 {
            self.checkpoint_in_background();
        }
    }

    /// The frames waiting to be encoded, for [`crate::sim::with_workers_awake_and`]'s idle work; `None` for a
    /// format whose encoder does not pause for the pool's jobs (its frames are tasks of the pool instead).
    pub fn idle_work(&self) -> Option<crate::sim::IdleWork> {
        let queue = Arc::clone(&self.queue);
        self.queue.pauses().then(|| Arc::new(move || queue.run_one()) as crate::sim::IdleWork)
    }

    /// Waits until at least one more frame is back: encodes a waiting frame on this thread, or, when none waits
    /// (every frame out is being encoded), sleeps on the channel until one comes back.
    fn wait_for_one(&mut self) {
        let before = self.returned;
        while self.returned == before {
            self.collect();
            if self.returned != before || self.queue.run_one() {
                continue;
            }
            if let Ok(done) = self.done.recv() {
                self.take(done);
            }
            self.collect();
        }
    }

    /// Waits until every frame handed out is back.
    fn wait_for_all(&mut self) {
        while self.returned < self.sent {
            self.wait_for_one();
        }
    }

    /// Takes finished frames off the done channel and commits the contiguous ones.
    fn collect(&mut self) {
        while let Ok(done) = self.done.try_recv() {
            self.take(done);
        }
        self.commit();
    }

    /// Files a frame back from its task.
    fn take(&mut self, done: Done) {
        self.returned += 1;
        self.unsynced.extend(done.files);
        if self.spare.len() < 8 {
            self.spare.push(done.frame);
        }
        match done.result {
            Ok(()) => {
                self.pending.insert(done.index, done.labels);
            }
            Err(e) => {
                self.error.get_or_insert(e);
            }
        }
    }

    /// Commits the frames back in order.
    fn commit(&mut self) {
        while let Some(labels) = self.pending.remove(&self.committed) {
            self.labels.push(|t| {
                t.push_str(&serde_json::to_string(&labels).expect("labels serialize"));
                t.push('\n');
            });
            self.mot.push(|t| labels.push_mot_lines(t));
            self.committed += 1;
        }
    }

    /// Makes the frames written so far durable with the new label and MOT lines, then puts the labels, the MOT file
    /// and the manifest in place (see [`ShadowedText`]): the
    /// labels on disk never list a frame that a crash of the machine could lose. Waits for a checkpoint being
    /// written in the background first.
    fn checkpoint(&mut self, status: &str) -> Result<(), RecordError> {
        self.settle_checkpoint(true);
        let job = self.checkpoint_job(status);
        let frames = job.frames;
        let outcome = job.write();
        self.apply_checkpoint(frames, outcome)
    }

    /// Starts a `running` checkpoint on a thread of its own, so that the simulation does not wait for the disk;
    /// does nothing while the last one is still being written (the next frame tries again). Where no thread can
    /// be started, writes it on this one.
    fn checkpoint_in_background(&mut self) {
        if self.writing.as_ref().is_some_and(|w| !w.handle.is_finished()) {
            return;
        }
        self.settle_checkpoint(false);
        if self.error.is_some() {
            return;
        }
        let job = self.checkpoint_job("running");
        let (frames, files) = (job.frames, job.unsynced.iter().map(|w| w.path.clone()).collect());
        match std::thread::Builder::new().name("irsim checkpoint".into()).spawn(move || job.write()) {
            Ok(handle) => self.writing = Some(Writing { handle, frames, files }),
            Err(_) => {
                self.unsynced.extend(files.into_iter().map(Written::by_path));
                if let Err(e) = self.checkpoint("running") {
                    self.error.get_or_insert(e);
                }
            }
        }
    }

    /// Takes the result of the checkpoint written in the background, if there is one (waiting for it with
    /// `wait`; otherwise only if it is done).
    fn settle_checkpoint(&mut self, wait: bool) {
        if !(wait || self.writing.as_ref().is_some_and(|w| w.handle.is_finished())) {
            return;
        }
        if let Some(Writing { handle, frames, files }) = self.writing.take() {
            let outcome = handle.join().unwrap_or_else(|_| CheckpointOutcome {
                result: Err((
                    Reached::Nothing,
                    RecordError::Io { path: self.dir.display().to_string(), message: "checkpoint failed".into() },
                )),
                unsynced: files.into_iter().map(Written::by_path).collect(),
                texts: None,
            });
            if let Err(e) = self.apply_checkpoint(frames, outcome) {
                self.error.get_or_insert(e);
            }
        }
    }

    /// What a checkpoint with `status` writes, now: the frames committed so far, the files to sync, the texts
    /// (unless the files on disk already hold them) and the manifest.
    fn checkpoint_job(&mut self, status: &str) -> CheckpointJob {
        let texts = !(self.texts_written && self.on_disk == self.committed);
        let progress = Progress {
            status: status.to_owned(),
            frames_requested: self.frames_requested,
            frames_written: self.committed,
            error: self.error.as_ref().map(ToString::to_string),
        };
        let mut m = self.manifest.clone();
        if let (Some(obj), Ok(serde_json::Value::Object(p))) = (m.as_object_mut(), serde_json::to_value(&progress)) {
            obj.extend(p);
        }
        self.last_checkpoint = Instant::now();
        let last = status != "running";
        let shadows = if last { self.shadow_paths() } else { Vec::new() };
        CheckpointJob {
            dir: self.dir.clone(),
            dir_handle: self.dir_handle.clone(),
            writeback: Arc::clone(&self.writeback.counts),
            frames: self.committed,
            unsynced: if texts { std::mem::take(&mut self.unsynced) } else { Vec::new() },
            texts: texts.then(|| {
                [self.labels.append_for(&self.dir, self.committed), self.mot.append_for(&self.dir, self.committed)]
            }),
            manifest: serde_json::to_string_pretty(&m).expect("manifest serializes"),
            last,
            shadows,
            done: [(false, false); 2],
        }
    }

    /// Files the outcome of a checkpoint of `frames` frames.
    fn apply_checkpoint(&mut self, frames: u64, outcome: CheckpointOutcome) -> Result<(), RecordError> {
        let CheckpointOutcome { result, mut unsynced, texts } = outcome;
        if let Some([labels, mot]) = texts {
            self.labels.applied(labels.0, labels.1, labels.2);
            self.mot.applied(mot.0, mot.1, mot.2);
        }
        // files it did not make durable are made so by the next checkpoint, before labels list them again
        if !unsynced.is_empty() {
            unsynced.append(&mut self.unsynced);
            self.unsynced = unsynced;
        }
        match result {
            Ok(()) => {
                self.texts_written = true;
                self.on_disk = frames;
                Ok(())
            }
            Err((reached, e)) => {
                if reached != Reached::Nothing {
                    // the labels list these frames; the MOT file is put in place next time unless it was too
                    self.on_disk = frames;
                    self.texts_written = reached == Reached::Texts;
                }
                Err(e)
            }
        }
    }

    /// Removes the texts' shadows' names, whatever state they are in (the files in place keep theirs): what a
    /// recording that ends without its last checkpoint, or after a failed one, would leave.
    fn remove_shadows(&self) {
        for p in self.shadow_paths() {
            let _ = std::fs::remove_file(p);
        }
    }

    /// The paths of both texts' shadows.
    fn shadow_paths(&self) -> Vec<PathBuf> {
        [&self.labels, &self.mot].iter().flat_map(|t| [t.shadow(&self.dir, 0), t.shadow(&self.dir, 1)]).collect()
    }

    /// Forgets the frames after the first `n` committed ones: their files, and their label and MOT lines.
    fn truncate_to(&mut self, n: u64) {
        let ext = self.format.extension();
        for i in n..self.sent {
            let _ = std::fs::remove_file(self.dir.join("frames").join(format!("{i:06}.{ext}")));
            let _ = std::fs::remove_file(self.dir.join("masks").join(format!("{i:06}.png")));
        }
        // the removed files are no longer to be synced
        if n < self.sent {
            self.unsynced.retain(|f| f.path.exists());
        }
        if n < self.committed {
            self.labels.truncate(n);
            self.mot.truncate(n);
            self.committed = n;
        }
    }

    /// Adds or replaces a top-level manifest entry (e.g. timings) for the next checkpoint.
    pub fn set_manifest(&mut self, key: &str, value: serde_json::Value) {
        if let Some(obj) = self.manifest.as_object_mut() {
            obj.insert(key.to_owned(), value);
        }
    }

    /// Waits for the tasks, commits what completed, removes frames beyond the committed ones, and writes
    /// the final labels and manifest. `interrupted` marks a run stopped by the user.
    ///
    /// # Errors
    /// The first write error of the run (the final files are still written if possible).
    pub fn finish(mut self, interrupted: bool) -> Result<Progress, RecordError> {
        self.wait_for_all();
        self.writeback.stop();
        self.collect();
        self.settle_checkpoint(true);
        // frames written after a gap (a failed frame) have no labels: remove them
        self.truncate_to(self.committed);
        let status = if self.error.is_some() {
            "failed"
        } else if interrupted || self.committed < self.frames_requested {
            "interrupted"
        } else {
            "complete"
        };
        let mut status = status;
        let mut final_write = self.checkpoint(status);
        if let Err(e) = final_write {
            // The labels could not be written (a full disk): keep only the frames the labels on disk describe,
            // which also frees space, and say so in the manifest.
            self.error.get_or_insert(e);
            status = "failed";
            self.truncate_to(self.on_disk);
            final_write = self.checkpoint(status);
            if let Err(e) = &final_write {
                eprintln!(
                    "error: cannot write {}: {e}; the directory holds {} frames with their labels",
                    self.dir.join("manifest.json").display(),
                    self.on_disk
                );
            }
        }
        let progress = Progress {
            status: status.to_owned(),
            frames_requested: self.frames_requested,
            frames_written: self.on_disk,
            error: self.error.as_ref().map(ToString::to_string),
        };
        match self.error.take() {
            Some(e) => Err(e),
            None => final_write.map(|()| progress),
        }
    }
}

impl Drop for Recorder {
    /// A recorder dropped without [`Recorder::finish`] (a caller's early return) still waits for its tasks, so
    /// that no file is written into the directory after it is gone.
    fn drop(&mut self) {
        self.wait_for_all();
        self.writeback.stop();
        self.settle_checkpoint(true);
        self.remove_shadows();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn the_writeback_thread_passes_only_after_writes_and_stops_at_once() {
        use std::sync::atomic::Ordering;
        use std::time::{Duration, Instant};
        let dir = std::env::temp_dir().join(format!("irsim-rec-writeback-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let passes = |wb: &Writeback| wb.counts.passes.each_ref().map(|p| p.load(Ordering::SeqCst));
        // each way, forced: one `syncfs`, and file by file
        for (forced, way) in [(1, SyncWay::FileSystem), (2, SyncWay::EachFile)] {
            let wb = Writeback::start(Some(&dir), (WRITEBACK_PERIOD, WRITEBACK_PERIOD));
            assert!(wb.thread.is_some());
            wb.counts.forced_way.store(forced, Ordering::SeqCst);
            // nothing written: no pass
            std::thread::sleep(WRITEBACK_PERIOD * 3);
            assert_eq!(passes(&wb), [0, 0]);
            // a file written: a pass within a few periods (a loaded machine may be slow to run the thread)
            let f = dir.join(format!("f{forced}"));
            std::fs::write(&f, b"frame").unwrap();
            wb.counts.wrote(&f, 5);
            let t = Instant::now();
            while passes(&wb) == [0, 0] && t.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(5));
            }
            let mut expected = [0, 0];
            expected[way as usize] = 1;
            assert_eq!(passes(&wb), expected, "{way:?}");
            assert_eq!(wb.counts.failed.load(Ordering::SeqCst), 0);
            // the pass took the list and forgot the bytes it handed to the disk
            assert!(wb.counts.take_pending().is_empty());
            assert_eq!(wb.counts.unsynced_bytes.load(Ordering::SeqCst), 0);
            // no more writes: no more passes
            std::thread::sleep(WRITEBACK_PERIOD * 3);
            assert_eq!(passes(&wb), expected);
            // a file removed before the pass (a failed run's frames) is no error
            wb.counts.wrote(&dir.join("gone"), 5);
            let t = Instant::now();
            while passes(&wb) == expected && t.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(5));
            }
            expected[way as usize] = 2;
            assert_eq!(passes(&wb), expected, "{way:?}");
            assert_eq!(wb.counts.failed.load(Ordering::SeqCst), 0);
        }
        // stopping wakes the thread from its wait, not a period later: with a period of a minute, a thread in
        // its wait (with files written or not) stops within seconds even on a loaded machine; after it stops,
        // files are no longer listed
        let long = Duration::from_secs(60);
        for written in [false, true] {
            let mut wb = Writeback::start(Some(&dir), (long, long));
            if written {
                wb.counts.wrote(&dir.join("f1"), 5);
            }
            std::thread::sleep(Duration::from_millis(20));
            let t = Instant::now();
            wb.stop();
            assert!(wb.thread.is_none());
            assert!(t.elapsed() < Duration::from_secs(5), "stopping took {:?}", t.elapsed());
            wb.counts.wrote(&dir.join("f1"), 5);
            assert!(wb.counts.take_pending().is_empty());
        }
        // the first passes come sooner than the period: waits of 5 ms, 10, 20… against a period of a minute, so a
        // pass within seconds of each file is one of the short waits (each wait missed doubles the next, which
        // reaches ten seconds only after a dozen)
        let mut wb = Writeback::start(Some(&dir), (Duration::from_millis(5), long));
        for n in 1..=3 {
            wb.counts.wrote(&dir.join("f1"), 5);
            let t = Instant::now();
            while passes(&wb).iter().sum::<u64>() < n && t.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(2));
            }
            assert_eq!(passes(&wb).iter().sum::<u64>(), n, "pass {n} after {:?}", t.elapsed());
        }
        wb.stop();
        // no directory: no thread, and nothing listed for one
        let wb = Writeback::start(None, (WRITEBACK_FIRST_WAIT, WRITEBACK_PERIOD));
        assert!(wb.thread.is_none());
        wb.counts.wrote(&dir.join("f1"), 5);
        assert!(wb.counts.take_pending().is_empty());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The write-back thread's waits double from the first up to the period, never 0 (a loop that would spin).
    #[test]
    fn the_writeback_waits_double_up_to_the_period() {
        use std::time::Duration;
        let ms = Duration::from_millis;
        let mut wait = WRITEBACK_FIRST_WAIT.min(WRITEBACK_PERIOD);
        let mut waits = vec![wait];
        for _ in 0..6 {
            wait = next_wait(wait, WRITEBACK_PERIOD);
            waits.push(wait);
        }
        assert_eq!(waits, [6, 12, 24, 48, 96, 100, 100].map(ms));
        // the passes documented on WRITEBACK_FIRST_WAIT: 6, 18, 42, 90 and 186 ms into the recording
        let mut t = Duration::ZERO;
        let at: Vec<Duration> = waits
            .iter()
            .map(|&w| {
                t += w;
                t
            })
            .collect();
        assert_eq!(at[..5], [6, 18, 42, 90, 186].map(ms));
        assert_eq!(next_wait(ms(200), ms(100)), ms(100));
        assert_eq!(next_wait(Duration::ZERO, ms(100)), ms(1));
        assert_eq!(next_wait(ms(30), ms(50)), ms(50));
    }

    /// A sync is one `syncfs` only while the machine holds little to write besides the recording's own files (a
    /// `syncfs` would wait for the rest too), and file by file where that cannot be told.
    #[test]
    fn the_sync_way_is_one_syncfs_only_while_little_else_waits() {
        let meminfo = "MemTotal:       32768000 kB\nDirty:              3000 kB\nWriteback:           100 kB\n\
                       WritebackTmp:          0 kB\n";
        assert_eq!(waiting_bytes(meminfo), Some(3100 * 1024));
        for broken in [
            "",
            "Dirty: 3000 kB\n",
            "Writeback: 1 kB\n",
            "Dirty: x kB\nWriteback: 1 kB\n",
            "Dirty: 3 MB\nWriteback: 1 kB\n",
        ] {
            assert_eq!(waiting_bytes(broken), None, "{broken:?}");
        }
        let limit = FOREIGN_DIRTY_LIMIT_BYTES;
        assert_eq!(SyncWay::choose(Some(0), 0), SyncWay::FileSystem);
        assert_eq!(SyncWay::choose(Some(limit), 0), SyncWay::FileSystem);
        assert_eq!(SyncWay::choose(Some(limit + 1), 0), SyncWay::EachFile);
        // the recording's own bytes are not others'
        assert_eq!(SyncWay::choose(Some(limit + (500 << 20)), 500 << 20), SyncWay::FileSystem);
        assert_eq!(SyncWay::choose(Some(100), 500 << 20), SyncWay::FileSystem);
        assert_eq!(SyncWay::choose(Some(u64::MAX), 0), SyncWay::EachFile);
        assert_eq!(SyncWay::choose(None, 0), SyncWay::EachFile);
        // this machine's own /proc/meminfo reads (where there is one)
        if let Ok(text) = std::fs::read_to_string("/proc/meminfo") {
            assert!(waiting_bytes(&text).is_some(), "{text}");
        }
    }

    /// Both ways of syncing (one `syncfs`, file by file) leave a recording whole: frames, masks, labels and
    /// manifest. File by file, every frame and mask, the three texts' temporaries, `frames/`, `masks/` and the
    /// output directory are synced, each file before its directory; a file that cannot be synced is reported by its
    /// path. The written files are held open until a checkpoint has synced them, and none is left open after.
    #[test]
    fn each_way_of_syncing_leaves_a_recording_whole() {
        use std::sync::atomic::Ordering;
        for (forced, way) in [(1, SyncWay::FileSystem), (2, SyncWay::EachFile)] {
            let (dir, _lock, mut rec) = fresh_recorder(&format!("way-{forced}"), true, 65535, 10);
            let counts = Arc::clone(&rec.writeback.counts);
            counts.forced_way.store(forced, Ordering::SeqCst);
            // the recorder's first checkpoint (its manifest) was synced the way this machine picked
            counts.synced_paths.lock().unwrap().clear();
            for k in 0..10 {
                rec.push(Frame::new(8, 8), Some(vec![0; 64]), labels(k));
            }
            rec.wait_for_all();
            // where files are written unnamed (Linux, most file systems), each is held open until its sync (unless
            // a slow machine took more than a second, and a checkpoint has taken some already)
            if cfg!(target_os = "linux") && rec.queue.spec.unnamed.load(Ordering::SeqCst) && rec.writing.is_none() {
                assert_eq!(counts.held.load(Ordering::SeqCst), 20, "{way:?}");
                assert_eq!(rec.unsynced.iter().filter(|w| w.file.is_some()).count(), 20);
            }
            let p = rec.finish(false).unwrap();
            assert_eq!(counts.held.load(Ordering::SeqCst), 0, "{way:?}: files left open");
            assert_eq!((p.status.as_str(), p.frames_written), ("complete", 10), "{way:?}");
            assert_eq!(std::fs::read_to_string(dir.join("labels.jsonl")).unwrap().lines().count(), 10);
            for sub in ["frames", "masks"] {
                assert_eq!(std::fs::read_dir(dir.join(sub)).unwrap().count(), 10, "{way:?} {sub}");
            }
            let names: Vec<String> =
                std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
            assert!(!names.iter().any(|n| n.ends_with(".tmp")), "{way:?}: {names:?}");
            // nor the texts' shadows
            assert!(!names.iter().any(|n| n.starts_with(".labels") || n.starts_with(".gt_mot")), "{way:?}: {names:?}");
            let m: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
            assert_eq!(m["status"], "complete");
            assert_eq!(m["frames_written"], 10);
            let synced = std::mem::take(&mut *counts.synced_paths.lock().unwrap());
            if way == SyncWay::EachFile && cfg!(target_os = "linux") {
                // each file, then its directory after it (a checkpoint in the background, on a slow machine, may have
                // synced some files and their directory before the last one)
                let synced_then = |file: &Path, parent: &Path| {
                    let at = synced.iter().position(|s| s == file).unwrap_or_else(|| panic!("{file:?} not synced"));
                    assert!(synced[at..].iter().any(|s| s == parent), "{file:?} not followed by {parent:?}");
                };
                for k in 0..10 {
                    for sub in ["frames", "masks"] {
                        synced_then(&dir.join(sub).join(format!("{k:06}.png")), &dir.join(sub));
                    }
                }
                // the texts' shadows the last checkpoint appended to, and the manifest's temporary
                for text in ["labels.jsonl", "gt_mot.txt"] {
                    let shadow = (0..2).map(|k| dir.join(format!(".{text}.{k}"))).find(|p| synced.contains(p));
                    synced_then(&shadow.unwrap_or_else(|| panic!("no shadow of {text} synced: {synced:?}")), &dir);
                }
                synced_then(&temporary_of(&dir.join("manifest.json")), &dir);
                // the last checkpoint syncs the output directory once more, after the renames
                assert_eq!(synced.last(), Some(&dir));
            } else if cfg!(target_os = "linux") {
                assert_eq!(synced, Vec::<PathBuf>::new(), "one syncfs syncs no file on its own");
            }
            // a file gone before its sync, alone with another and among 20 (synced on threads side by side)
            let counts = WritebackCounts::default();
            counts.forced_way.store(forced, Ordering::SeqCst);
            let gone = dir.join("frames").join("999999.png");
            let frame = |k: usize| dir.join(["frames", "masks"][k % 2]).join(format!("{:06}.png", k / 2));
            for mut files in [vec![frame(0)], (0..19).map(frame).collect()] {
                files.insert(files.len() / 2, gone.clone());
                let files: Vec<Written> = files.into_iter().map(Written::by_path).collect();
                let synced = sync_written(&dir, None, (&files, &[]), &counts);
                if way == SyncWay::FileSystem && cfg!(target_os = "linux") {
                    synced.unwrap();
                } else {
                    let e = synced.unwrap_err().to_string();
                    assert!(e.contains("999999.png"), "{e}");
                }
            }
            // the 20 files' syncs ran on threads side by side
            if way == SyncWay::EachFile || !cfg!(target_os = "linux") {
                assert_eq!(counts.most_sync_threads.load(Ordering::SeqCst), 2);
            }
            std::fs::remove_dir_all(&dir).unwrap();
        }
    }

    /// Files are held open within the budget only, and closed when dropped.
    #[test]
    fn written_files_are_held_open_within_the_budget() {
        use std::sync::atomic::Ordering;
        let counts = Arc::new(WritebackCounts::default());
        counts.max_held.store(2, Ordering::SeqCst);
        let open = || std::fs::File::open(std::env::current_exe().unwrap()).unwrap();
        let kept: Vec<Option<Held>> = (0..3).map(|_| Held::keep(&counts, open())).collect();
        assert_eq!(kept.iter().map(Option::is_some).collect::<Vec<_>>(), [true, true, false]);
        assert_eq!(counts.held.load(Ordering::SeqCst), 2);
        drop(kept);
        assert_eq!(counts.held.load(Ordering::SeqCst), 0);
        assert!(Held::keep(&counts, open()).is_some());
        // the process's budget: some files on Linux (a quarter of a limit of at least 64), none elsewhere
        if cfg!(target_os = "linux") {
            assert!((16..=8192).contains(&descriptor_budget()), "{}", descriptor_budget());
        } else {
            assert_eq!(descriptor_budget(), 0);
        }
    }

    /// A file written without a name appears under its name whole, with nothing beside it; where it cannot be
    /// (the name taken, no directory) the caller is told to write it the other way, and only a missing feature
    /// turns the way off for the run.
    #[cfg(target_os = "linux")]
    #[test]
    fn an_unnamed_file_is_linked_whole_or_handed_back() {
        use std::sync::atomic::{AtomicBool, Ordering};
        let dir = std::env::temp_dir().join(format!("irsim-rec-unnamed-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let bytes: Vec<u8> = (0..40_000u32).map(|k| (k % 251) as u8).collect();
        let unnamed = AtomicBool::new(true);
        let mut pauses = 0;
        let path = dir.join("000000.png");
        // whether the file system takes unnamed files, asked directly
        let supported = {
            use std::os::unix::fs::OpenOptionsExt;
            std::fs::OpenOptions::new().write(true).custom_flags(libc::O_TMPFILE).open(&dir).is_ok()
        };
        let written = write_unnamed_pausing(&path, &bytes, &mut || pauses += 1, &unnamed);
        assert_eq!(written.is_some(), supported);
        // where the file system has no O_TMPFILE (some do not), the way is off and nothing is left
        if written.is_none() {
            assert!(!unnamed.load(Ordering::Relaxed));
            assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
            std::fs::remove_dir_all(&dir).unwrap();
            return;
        }
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        // made with the umask, as a file made by name (the recorder's probe says so, and leaves nothing behind)
        assert!(unnamed_files_fit(&dir));
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        let named = dir.join("named");
        std::fs::write(&named, b"x").unwrap();
        let mode = |p: &Path| std::os::unix::fs::PermissionsExt::mode(&std::fs::metadata(p).unwrap().permissions());
        assert_eq!(mode(&path), mode(&named));
        std::fs::remove_file(&named).unwrap();
        assert!(!unnamed_files_fit(&dir.join("missing")));
        // a pause per PAUSE_BYTES piece written and one before the link
        assert_eq!(pauses, bytes.len().div_ceil(crate::imaging::png16::PAUSE_BYTES) + 1);
        // the name taken: handed back, the file as it was, the way still on
        assert!(write_unnamed_pausing(&path, b"other", &mut || {}, &unnamed).is_none());
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        assert!(unnamed.load(Ordering::Relaxed));
        // a directory that is not there: handed back (the other way reports the error)
        assert!(write_unnamed_pausing(&dir.join("no").join("f.png"), b"x", &mut || {}, &unnamed).is_none());
        assert!(unnamed.load(Ordering::Relaxed));
        // the way off: handed back at once, nothing written
        unnamed.store(false, Ordering::Relaxed);
        assert!(write_unnamed_pausing(&dir.join("000001.png"), b"x", &mut || {}, &unnamed).is_none());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn npy_header_is_aligned_and_parsable() {
        let f = Frame::from_pixels(3, 2, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.5]);
        let mut b = Vec::new();
        write_npy_f32(&f, &mut b);
        let header_len = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + header_len) % 64, 0);
        assert!(std::str::from_utf8(&b[10..10 + header_len]).unwrap().contains("'shape': (2, 3)"));
        assert_eq!(b.len(), 10 + header_len + 6 * 4);
        assert_eq!(f32::from_le_bytes(b[b.len() - 4..].try_into().unwrap()), 6.5);
    }

    /// A recorder of 16-bit PNGs (`fast`) for 2 threads into a fresh directory of the temporary directory, named
    /// after `name`: the directory, its lock (held while it is kept) and the recorder.
    fn fresh_recorder(name: &str, masks: bool, max_level: u16, frames: u64) -> (PathBuf, DirLock, Recorder) {
        let dir = std::env::temp_dir().join(format!("irsim-rec-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let lock = prepare_dir(&dir, false).unwrap();
        let png = (FrameFormat::Png16, PngCompression::Fast);
        let rec = Recorder::new(&dir, png, masks, max_level, 2, serde_json::json!({}), frames).unwrap();
        (dir, lock, rec)
    }

    fn labels(frame: u64) -> FrameLabels {
        FrameLabels { frame, t_s: frame as f64 * 0.1, targets: Vec::new() }
    }

    /// A text is appended, checkpoint after checkpoint, to two hidden files in turn, each linked in place when
    /// synced: the file under the name always holds every line so far, a checkpoint writes only the lines its shadow
    /// lacks, memory keeps only those not in both, a failed append's bytes are cut, forgotten frames are cut from
    /// both, and the file in place is never written.
    #[test]
    fn texts_are_appended_to_two_shadows_in_turn_and_never_written_in_place() {
        let dir = std::env::temp_dir().join(format!("irsim-rec-shadow-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut t = ShadowedText::new("labels.jsonl");
        let line = |k: u64| format!("{{\"frame\":{k:04}}}\n");
        let per_frame = line(0).len();
        let mut all = String::new();
        let in_place = || std::fs::read_to_string(dir.join("labels.jsonl")).unwrap();
        let checkpoint = |t: &mut ShadowedText| {
            let a = t.append_for(&dir, t.ends.len() as u64);
            a.write().unwrap();
            a.show().unwrap();
            t.applied((a.slot, a.frames), true, true);
            a.bytes.len()
        };
        let mut files = Vec::new();
        for round in 0..5u64 {
            for k in 3 * round..3 * round + 3 {
                t.push(|s| s.push_str(&line(k)));
                all.push_str(&line(k));
            }
            let appended = checkpoint(&mut t);
            assert_eq!(in_place(), all, "round {round}");
            // the lines since the checkpoint before last, not the whole text
            assert_eq!(appended, per_frame * if round == 0 { 3 } else { 6 });
            // in memory: the lines the other shadow lacks
            assert_eq!(t.text.len(), per_frame * 3, "round {round}");
            #[cfg(unix)]
            files.push(std::os::unix::fs::MetadataExt::ino(&std::fs::metadata(dir.join("labels.jsonl")).unwrap()));
        }
        // two files take turns under the name
        #[cfg(unix)]
        assert!(files[0] == files[2] && files[1] == files[3] && files[0] != files[1], "{files:?}");
        // bytes a failed append left in the shadow not in place are cut before the next
        let free = t.shadow(&dir, 1 - t.shown.unwrap());
        std::fs::OpenOptions::new().append(true).open(&free).unwrap().write_all(b"half a li").unwrap();
        t.push(|s| s.push_str(&line(15)));
        all.push_str(&line(15));
        checkpoint(&mut t);
        assert_eq!(in_place(), all);
        // frames forgotten below what both shadows hold: the next checkpoint lists only those kept
        t.truncate(4);
        t.push(|s| s.push_str(&line(99)));
        let kept: String = (0..4).map(line).chain([line(99)]).collect();
        checkpoint(&mut t);
        assert_eq!(in_place(), kept);
        checkpoint(&mut t);
        assert_eq!(in_place(), kept, "the other shadow, cut back too");
        // the shadow in place is never written, even when a checkpoint's outcome was lost
        #[cfg(unix)]
        {
            let shown = t.shown.unwrap();
            let lost = Append {
                slot: shown,
                frames: 0,
                shadow: t.shadow(&dir, shown),
                keep: 0,
                bytes: "x".into(),
                name: dir.join("labels.jsonl"),
            };
            assert!(lost.write().is_err());
            assert_eq!(in_place(), kept);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A checkpoint that fails hands back the files it did not make durable (the next one syncs them before its
    /// labels list them) and says how far it got (labels written and not the MOT file: the labels are what is on
    /// disk).
    #[test]
    fn a_failed_checkpoint_hands_back_its_files_and_says_how_far_it_got() {
        let paths = |w: &[Written]| w.iter().map(|w| w.path.clone()).collect::<Vec<_>>();
        let dir = std::env::temp_dir().join(format!("irsim-rec-ckpt-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("frames")).unwrap();
        let frame = dir.join("frames").join("000000.png");
        std::fs::write(&frame, b"frame").unwrap();
        let job = |d: &Path| CheckpointJob {
            dir: d.to_path_buf(),
            // as the recorder holds it (none where the directory is missing: the sync opens the path, and fails)
            dir_handle: std::fs::File::open(d).ok().map(Arc::new),
            writeback: Arc::default(),
            frames: 1,
            unsynced: vec![Written::by_path(frame.clone())],
            texts: Some({
                let one = |name, line: &str| {
                    let mut text = ShadowedText::new(name);
                    text.push(|t| t.push_str(line));
                    text.append_for(d, 1)
                };
                [one("labels.jsonl", "labels\n"), one("gt_mot.txt", "mot\n")]
            }),
            manifest: "{}".into(),
            last: true,
            shadows: Vec::new(),
            done: [(false, false); 2],
        };
        // the temporary files of the texts, which a failed checkpoint leaves none of
        let temporaries = |d: &Path| -> Vec<String> {
            std::fs::read_dir(d)
                .unwrap()
                .filter_map(|e| e.ok()?.file_name().into_string().ok())
                .filter(|n| n.ends_with(".tmp"))
                .collect()
        };
        // a directory that is not there: the sync fails, nothing is written, the file comes back
        let out = job(&dir.join("missing")).write();
        assert!(matches!(out.result, Err((Reached::Nothing, _))), "{:?}", out.result.err());
        assert_eq!(paths(&out.unsynced), std::slice::from_ref(&frame));
        // neither text's lines are its shadow's, nor in place
        assert_eq!(out.texts, Some([((0, 1), false, false); 2]));
        // a failed pass of the writeback thread (Linux): the sync succeeds, the pass's error is reported
        #[cfg(target_os = "linux")]
        {
            let failing = job(&dir);
            failing.writeback.pass_failed(Some(libc::EIO), Some(&frame));
            let out = failing.write();
            let Err((Reached::Nothing, e)) = &out.result else { panic!("{:?}", out.result.err()) };
            assert!(e.to_string().contains(&std::io::Error::from_raw_os_error(libc::EIO).to_string()), "{e}");
            // on the file it failed on
            assert!(e.to_string().contains("000000.png"), "{e}");
            assert_eq!(paths(&out.unsynced), std::slice::from_ref(&frame));
            // appended but not synced: the next checkpoint appends the lines again
            assert_eq!(out.texts, Some([((0, 1), false, false); 2]));
            assert!(!dir.join("labels.jsonl").exists());
            assert_eq!(temporaries(&dir), Vec::<String>::new());
        }
        // the MOT file's name taken by a directory: the labels are written, the MOT file is not
        std::fs::create_dir_all(dir.join("gt_mot.txt")).unwrap();
        let out = job(&dir).write();
        assert!(matches!(out.result, Err((Reached::Labels, _))), "{:?}", out.result.err());
        assert!(out.unsynced.is_empty(), "synced before the labels were written");
        // both texts' lines synced into their shadows; the labels' in place, the MOT lines' not
        assert_eq!(out.texts, Some([((0, 1), true, true), ((0, 1), true, false)]));
        assert_eq!(std::fs::read_to_string(dir.join("labels.jsonl")).unwrap(), "labels\n");
        assert!(!dir.join("manifest.json").exists(), "the manifest is not put in place ahead of the MOT file");
        assert_eq!(temporaries(&dir), Vec::<String>::new());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn interruption_leaves_matching_frames_labels_and_manifest() {
        let (dir, _lock, mut rec) = fresh_recorder("int", false, 65535, 10);
        for k in 0..3 {
            rec.push(Frame::new(8, 8), None, labels(k));
        }
        let p = rec.finish(true).unwrap();
        assert_eq!((p.status.as_str(), p.frames_written), ("interrupted", 3));
        assert_eq!(std::fs::read_to_string(dir.join("labels.jsonl")).unwrap().lines().count(), 3);
        assert_eq!(std::fs::read_dir(dir.join("frames")).unwrap().count(), 3);
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
        assert_eq!(m["status"], "interrupted");
        assert_eq!(m["frames_written"], 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The three ways frames get encoded write the same files: by the pool's idle workers while frames are made
    /// (`with_workers_awake_and`), by the recording thread itself (a pool of one), and by tasks of the global pool
    /// (a recorder outside any pool).
    #[test]
    fn frames_are_the_same_whoever_encodes_them() {
        let record = |name: &str| {
            let (dir, _lock, mut rec) = fresh_recorder(name, true, 4095, 40);
            let idle = rec.idle_work();
            // the workers held awake over the whole loop, as `irsim record` holds them: the recorder waits for
            // frames (and encodes them itself) while they look for work
            crate::sim::with_workers_awake_and(idle.as_ref(), || {
                for k in 0..40u64 {
                    // some parallel work, as a frame's stages have
                    use rayon::prelude::*;
                    let px: Vec<f32> =
                        (0..96 * 64).into_par_iter().map(|i| ((i as u64 * 7919 + k * 104_729) % 4096) as f32).collect();
                    let mask = (0..96 * 64).map(|i| u8::from(i % 97 == 0)).collect();
                    rec.push(Frame::from_pixels(96, 64, px), Some(mask), labels(k));
                }
            });
            let p = rec.finish(false).unwrap();
            assert_eq!((p.status.as_str(), p.frames_written), ("complete", 40));
            let mut files = Vec::new();
            for sub in ["frames", "masks"] {
                let mut names: Vec<_> = std::fs::read_dir(dir.join(sub)).unwrap().map(|e| e.unwrap().path()).collect();
                names.sort();
                files.extend(names.iter().map(|f| std::fs::read(f).unwrap()));
            }
            files.push(std::fs::read(dir.join("labels.jsonl")).unwrap());
            std::fs::remove_dir_all(&dir).unwrap();
            files
        };
        let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let a = two.install(|| record("two"));
        assert_eq!(a.len(), 81);
        assert_eq!(a, one.install(|| record("one")));
        assert_eq!(a, record("outside"));
    }

    #[test]
    fn a_write_error_is_reported_and_recorded() {
        let (dir, _lock, mut rec) = fresh_recorder("err", false, 65535, 10);
        rec.push(Frame::new(8, 8), None, labels(0));
        // make every later frame write fail, as a full disk would
        std::fs::remove_dir_all(dir.join("frames")).unwrap();
        std::fs::write(dir.join("frames"), b"not a directory").unwrap();
        for k in 1..6 {
            rec.push(Frame::new(8, 8), None, labels(k));
        }
        let err = rec.finish(false).unwrap_err().to_string();
        assert!(err.contains("frames"), "{err}");
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
        assert_eq!(m["status"], "failed");
        let written = m["frames_written"].as_u64().unwrap();
        assert!(written <= 1);
        assert_eq!(std::fs::read_to_string(dir.join("labels.jsonl")).unwrap().lines().count() as u64, written);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failure_the_caller_reports_ends_the_run_as_failed() {
        let (dir, _lock, mut rec) = fresh_recorder("fail", false, 65535, 10);
        rec.push(Frame::new(8, 8), None, labels(0));
        rec.fail("internal error computing frame 1".into());
        assert!(rec.failed());
        assert!(rec.finish(false).unwrap_err().to_string().contains("internal error"));
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
        assert_eq!((m["status"].as_str(), m["frames_written"].as_u64()), (Some("failed"), Some(1)));
        assert_eq!(std::fs::read_dir(dir.join("frames")).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_prepared_directory_holds_frames_and_its_lock_and_is_marked_to_spread() {
        let dir = std::env::temp_dir().join(format!("irsim-rec-spread-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let lock = prepare_dir(&dir, false).unwrap();
        let names = |d: &Path| {
            let mut n: Vec<String> =
                std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
            n.sort();
            n
        };
        // the subdirectory made under a name of its own is renamed into place: nothing else is left
        assert_eq!(names(&dir), [LOCK_FILE, "frames"]);
        make_subdirectory(&dir, "masks").unwrap();
        make_subdirectory(&dir, "masks").unwrap();
        assert_eq!(names(&dir), [LOCK_FILE, "frames", "masks"]);
        #[cfg(target_os = "linux")]
        {
            use std::os::fd::AsRawFd;
            // where the file system keeps the attribute (ext4; not tmpfs), the directory is the top of a hierarchy
            let probe = std::fs::File::open(&dir).unwrap();
            let mut flags: libc::c_int = 0;
            // SAFETY: an open descriptor and an int the call writes
            if unsafe { libc::ioctl(probe.as_raw_fd(), libc::FS_IOC_GETFLAGS, &mut flags) } == 0 {
                let supported = std::env::temp_dir().join(format!("irsim-rec-spread-probe-{}", std::process::id()));
                std::fs::create_dir_all(&supported).unwrap();
                let probe = std::fs::File::open(&supported).unwrap();
                let mut wanted: libc::c_int = 0;
                // SAFETY: as above; the calls write, then read, `wanted`
                let settable = unsafe {
                    libc::ioctl(probe.as_raw_fd(), libc::FS_IOC_GETFLAGS, &mut wanted) == 0 && {
                        wanted |= 0x0002_0000;
                        libc::ioctl(probe.as_raw_fd(), libc::FS_IOC_SETFLAGS, &wanted) == 0
                    }
                };
                let _ = std::fs::remove_dir_all(&supported);
                if settable {
                    assert_ne!(flags & 0x0002_0000, 0, "the output directory was not marked");
                }
            }
        }
        drop(lock);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn refuses_a_non_empty_directory_without_force() {
        let dir = std::env::temp_dir().join(format!("irsim-rec-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("keep.txt"), "mine").unwrap();
        // what a killed recording leaves: a subdirectory made and not yet renamed, a labels file being written
        std::fs::create_dir_all(dir.join(".frames.123.1764322211000000000.tmp")).unwrap();
        std::fs::write(dir.join("labels.jsonl.tmp"), "half").unwrap();
        // and the hidden copies its labels and MOT lines were appended to
        for shadow in [".labels.jsonl.0", ".labels.jsonl.1", ".gt_mot.txt.0", ".gt_mot.txt.1"] {
            std::fs::write(dir.join(shadow), "lines").unwrap();
        }
        // and names alike that are not a recording's
        for other in [".frames.tmp", ".frames.12a.tmp", ".masks..tmp", "labels.jsonl.tmp.bak", ".labels.jsonl.2"] {
            std::fs::write(dir.join(other), "mine").unwrap();
        }
        assert!(matches!(prepare_dir(&dir, false), Err(RecordError::NotEmpty(_))));
        drop(prepare_dir(&dir, true).unwrap());
        // --force removes only a run's outputs
        let mut names: Vec<String> =
            std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        assert_eq!(
            names,
            [
                ".frames.12a.tmp",
                ".frames.tmp",
                ".labels.jsonl.2",
                ".masks..tmp",
                "frames",
                "keep.txt",
                "labels.jsonl.tmp.bak"
            ]
        );
        assert_eq!(std::fs::read_to_string(dir.join("keep.txt")).unwrap(), "mine");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
