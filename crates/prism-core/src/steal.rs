//! How much of the machine's CPU time the hypervisor gave to others while prism ran: the
//! `steal` time of Linux's `/proc/stat`, over a stretch of work ([`StealProbe`]).
//!
//! On a virtual machine a benchmark can be slowed by guests it cannot see: their work is not
//! in `top`, but the kernel counts the time the hypervisor kept a virtual CPU from running as
//! steal. A timing taken while the steal share was high is not comparable with one taken
//! while it was near zero, so the benchmarks and the quick start report it beside their times.

/// Cumulative CPU time of all the machine's CPUs, in clock ticks, from the aggregate `cpu`
/// line of `/proc/stat`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CpuTimes {
    /// All the time the line accounts for: user, nice, system, idle, iowait, irq, softirq and
    /// steal (guest time is already inside user and nice).
    pub total: u64,
    /// Time a virtual CPU was ready to run and the hypervisor ran something else.
    pub steal: u64,
}

impl CpuTimes {
    /// Parses the aggregate `cpu` line of a `/proc/stat` text; `None` when there is none or it
    /// has fewer than the eight fields up to steal (kernels before 2.6.11).
    pub fn parse(stat: &str) -> Option<Self> {
        let line = stat
            .lines()
            .find(|l| l.split_whitespace().next() == Some("cpu"))?;
        let fields: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .take(8)
            .map(|f| f.parse().ok())
            .collect::<Option<_>>()?;
        (fields.len() == 8).then(|| Self {
            total: fields.iter().sum(),
            steal: fields[7],
        })
    }

    /// The machine's counters now; `None` where there is no readable `/proc/stat` (not
    /// Linux).
    pub fn now() -> Option<Self> {
        Self::parse(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// The share of the CPU time between `earlier` and these counters that was stolen, in
    /// [0, 1]; `None` when no time passed (both readings within one clock tick).
    pub fn steal_share_since(&self, earlier: &Self) -> Option<f64> {
        let total = self.total.saturating_sub(earlier.total);
        let steal = self.steal.saturating_sub(earlier.steal);
        (total > 0).then(|| steal as f64 / total as f64)
    }
}

/// The steal share of a stretch of work: started before it, read after it.
#[derive(Clone, Copy, Debug)]
pub struct StealProbe(Option<CpuTimes>);

impl StealProbe {
    /// Starts measuring now.
    pub fn start() -> Self {
        Self(CpuTimes::now())
    }

    /// The share of the machine's CPU time stolen since [`StealProbe::start`], in [0, 1];
    /// `None` where the counters cannot be read or no tick passed.
    pub fn share(&self) -> Option<f64> {
        CpuTimes::now()?.steal_share_since(&self.0?)
    }
}

/// `share` as a percentage with one decimal (`4.9%`), or `n/a`.
pub fn percent(share: Option<f64>) -> String {
    share.map_or_else(|| "n/a".to_string(), |s| format!("{:.1}%", 100.0 * s))
}

#[cfg(test)]
mod tests {
    use super::*;

    const STAT: &str = "cpu  2401582 8 167049 854270 9203 0 3279 45491 0 0\n\
                        cpu0 1288137 4 81010 345421 3099 0 315 22410 0 0\n\
                        intr 123 4 5\n";

    #[test]
    fn the_aggregate_line_is_summed_up_to_steal() {
        let t = CpuTimes::parse(STAT).unwrap();
        assert_eq!(t.steal, 45491);
        assert_eq!(t.total, 2401582 + 8 + 167049 + 854270 + 9203 + 3279 + 45491);
    }

    #[test]
    fn the_share_is_the_stolen_part_of_the_time_between_readings() {
        let earlier = CpuTimes {
            total: 1000,
            steal: 10,
        };
        let later = CpuTimes {
            total: 3000,
            steal: 110,
        };
        assert_eq!(later.steal_share_since(&earlier), Some(0.05));
        assert_eq!(earlier.steal_share_since(&earlier), None);
        assert_eq!(percent(Some(0.049)), "4.9%");
        assert_eq!(percent(None), "n/a");
    }

    #[test]
    fn lines_without_steal_or_numbers_are_refused() {
        assert_eq!(CpuTimes::parse("cpu 1 2 3 4\n"), None);
        assert_eq!(CpuTimes::parse("cpu 1 2 3 4 5 6 7 x\n"), None);
        assert_eq!(CpuTimes::parse("cpu0 1 2 3 4 5 6 7 8\n"), None);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn this_machine_reports_a_share_over_a_busy_stretch() {
        let probe = StealProbe::start();
        let start = std::time::Instant::now();
        let mut x = 0u64;
        while start.elapsed() < std::time::Duration::from_millis(30) {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        let share = probe.share().expect("a tick passes in 30 ms");
        assert!((0.0..=1.0).contains(&share), "{share}");
    }
}
