//! How much of the machine's CPU time its host took while a timing ran: the steal time of a virtual machine.
//!
//! On a shared host a virtual machine's CPUs are not always given a physical core: the kernel counts the ticks a
//! CPU was ready to run but not run as steal time (the eighth number of `/proc/stat`'s `cpu` line). Timings made
//! while the host took a large share of the time measure the host's other tenants more than irsim: on a
//! 2-CPU machine whose host took 30–48 % of the time, a 640 × 512 scenario ran slower on two threads than on one
//! (`irsim bench` on `scenarios/crossing_pair.toml`, `vmstat 1` beside it). `irsim bench` and `irsim bench
//! --limits` say so beside the times they print, `irsim bench report` gives the share over its run, and `irsim
//! record` after its summary and in the manifest's timings. On a machine without `/proc/stat` (not Linux) nothing
//! is measured or said.

/// The CPU time counters of the `cpu` line of `/proc/stat`, summed over the machine's CPUs, in ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuTicks {
    /// Every tick counted: user, nice, system, idle, iowait, irq, softirq and steal.
    pub total: u64,
    /// Ticks a CPU was ready to run but its host ran something else.
    pub steal: u64,
}

impl CpuTicks {
    /// The counters of `/proc/stat`'s text: its first line, `cpu` followed by at least eight counters (kernels
    /// before 2.6.11 give no steal field: `None`, as for a text that is not `/proc/stat`'s).
    pub fn parse(stat: &str) -> Option<Self> {
        let line = stat.lines().next()?;
        let mut fields = line.split_ascii_whitespace();
        if fields.next()? != "cpu" {
            return None;
        }
        // user nice system idle iowait irq softirq steal (guest and guest_nice are inside user and nice already)
        let counters: Vec<u64> = fields.take(8).map(|f| f.parse().ok()).collect::<Option<_>>()?;
        if counters.len() < 8 {
            return None;
        }
        Some(Self { total: counters.iter().sum(), steal: counters[7] })
    }

    /// The counters now, where the system has `/proc/stat`.
    pub fn now() -> Option<Self> {
        Self::parse(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// The ticks counted from `self` to `later` (a counter that went back, as the kernel's iowait may, counts
    /// none; the steal ticks are at most the total).
    pub fn elapsed(&self, later: &Self) -> Self {
        let total = later.total.saturating_sub(self.total);
        Self { total, steal: later.steal.saturating_sub(self.steal).min(total) }
    }

    /// The ticks counted from `before` (read earlier, if it could be) to now.
    pub fn since(before: Option<Self>) -> Option<Self> {
        Some(before?.elapsed(&Self::now()?))
    }

    /// Of ticks counted over a span ([`CpuTicks::elapsed`]), the share the host took, 0 to 1 (`None` when no
    /// tick was counted).
    pub fn share(&self) -> Option<f64> {
        (self.total > 0).then(|| self.steal as f64 / self.total as f64)
    }
}

/// The share of steal time from which [`steal_note`] speaks. An idle 2-CPU virtual machine (Intel Xeon, KVM) counted 0–1 %
/// (`vmstat 1`), one running irsim on both CPUs 1–2 % in quiet minutes and 30–48 % in busy ones: 5 % is a cut
/// between the two, chosen, not measured.
pub const STEAL_NOTE_FROM: f64 = 0.05;

/// A line for a timing that ran from `before` to now, where the host took at least [`STEAL_NOTE_FROM`] of the
/// CPU time ([`note_for_share`]).
pub fn steal_note(before: Option<CpuTicks>) -> Option<String> {
    note_for_share(CpuTicks::since(before)?.share()?)
}

/// The line for a timing during which the host took `share` (0 to 1) of the CPU time: its share, and that the
/// times may be slowed by it; none below [`STEAL_NOTE_FROM`].
pub fn note_for_share(share: f64) -> Option<String> {
    (share >= STEAL_NOTE_FROM).then(|| {
        format!(
            "  the host took {:.0} % of this machine's CPU time while this ran (steal time, /proc/stat): these \
             times may be slowed by other work on the host; time again when it is quieter",
            100.0 * share
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    // guest and guest_nice (the last two) are inside user and nice already: not summed
    const STAT: &str = "cpu  4705 356 584 3699176 23060 0 277 1200 900 40\ncpu0 1393280 32966 572056 13343292 6130 \
                        0 17875 600 450 20\nintr 1462898\n";

    #[test]
    fn parses_the_cpu_line_and_measures_the_share() {
        let before = CpuTicks::parse(STAT).expect("a /proc/stat text");
        assert_eq!(before.steal, 1200);
        assert_eq!(before.total, 4705 + 356 + 584 + 3_699_176 + 23_060 + 277 + 1200);
        // 1000 ticks later, 300 of them stolen
        let later = CpuTicks { total: before.total + 1000, steal: before.steal + 300 };
        assert_eq!(before.elapsed(&later).share(), Some(0.3));
        // nothing counted, or counters that went back: no share
        assert_eq!(before.elapsed(&before).share(), None);
        assert_eq!(later.elapsed(&before).share(), None);
        // the ticks in between, and none for counters that went back
        assert_eq!(before.elapsed(&later), CpuTicks { total: 1000, steal: 300 });
        assert_eq!(later.elapsed(&before), CpuTicks { total: 0, steal: 0 });
    }

    #[test]
    fn speaks_from_the_threshold_on() {
        assert_eq!(note_for_share(0.049), None);
        let note = note_for_share(0.31).expect("31 % is past the threshold");
        assert!(note.contains("took 31 %"), "{note}");
        assert!(note_for_share(STEAL_NOTE_FROM).is_some());
    }

    #[test]
    fn refuses_what_is_not_a_cpu_line() {
        assert_eq!(CpuTicks::parse("cpu0 1 2 3 4 5 6 7 8\n"), None);
        assert_eq!(CpuTicks::parse("cpu 1 2 3 4 5 6 7\n"), None, "no steal field");
        assert_eq!(CpuTicks::parse("cpu 1 2 3 x 5 6 7 8\n"), None);
        assert_eq!(CpuTicks::parse(""), None);
    }

    #[test]
    fn this_machine_counts_or_says_nothing() {
        // where the system has /proc/stat, its counters parse
        if std::path::Path::new("/proc/stat").exists() {
            assert!(CpuTicks::now().is_some());
        }
    }
}
