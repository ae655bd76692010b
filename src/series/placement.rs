//! Where the background encoder's threads run, and how eagerly, beside the
//! solver (docs/DESIGN.md "The encoder's threads beside the solver").
//!
//! A simulation rank is often bound to a few CPUs (`mpirun --bind-to core`,
//! `srun --cpu-bind`), and threads it starts inherit that set: an encoder
//! started by a rank bound to one core shares that core with the solver and
//! takes up to half of it. [`ThreadPlacement`] names the CPUs the
//! encoder's threads may run on (some the rank was given beyond the
//! solver's own) and their scheduling priority: `Low` (nice 19) or `Idle`
//! (Linux's `SCHED_IDLE`: the thread runs only when nothing else of the
//! machine wants its CPU), so that an encoder sharing the solver's core
//! takes only the time the solver leaves (an MPI wait that sleeps, I/O).
//! Each thread applies the placement to itself when the queue starts it.
//! Linux only; elsewhere anything but the inherited placement is refused.

use crate::error::{Error, Result};

/// The variable that names the encoder's CPUs, as a list (`8-15`,
/// `2,3,6-7`, or `@1` for the second of the creating thread's own:
/// [`parse_cpu_list`]); it overrides the configuration's.
pub const CPUS_VARIABLE: &str = "GSENC_ENCODER_CPUS";
/// The variable that sets the encoder's priority (`normal`, `low`, `idle`);
/// it overrides the configuration's.
pub const PRIORITY_VARIABLE: &str = "GSENC_ENCODER_PRIORITY";

/// The most CPUs a list may name (a CPU number at or past it is refused).
const MAX_CPUS: usize = 1 << 16;

/// How eagerly the encoder's threads take a CPU that the solver wants too.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Priority {
    /// As the solver's threads (the default).
    #[default]
    Normal,
    /// Nice 19: a small share of a CPU the solver wants.
    Low,
    /// `SCHED_IDLE`: only time no other thread wants. An encoder that shares
    /// a fully busy solver's CPUs then makes no progress: its queue fills
    /// and `when_full` decides.
    Idle,
}

impl Priority {
    /// `normal`, `low` or `idle`.
    pub fn parse(s: &str) -> Result<Priority> {
        match s.trim().to_ascii_lowercase().as_str() {
            "normal" => Ok(Priority::Normal),
            "low" => Ok(Priority::Low),
            "idle" => Ok(Priority::Idle),
            other => Err(Error::arg(format!("unknown encoder priority '{other}' (normal, low or idle)"))),
        }
    }
}

/// The CPUs and the priority of the encoder's threads.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ThreadPlacement {
    /// The CPUs the threads may run on, ascending; `None` keeps the set
    /// they inherit from the thread that starts the encoder.
    pub cpus: Option<Vec<usize>>,
    pub priority: Priority,
}

impl ThreadPlacement {
    /// This placement with what [`CPUS_VARIABLE`] and [`PRIORITY_VARIABLE`]
    /// set in place of its own.
    pub fn with_env(self) -> Result<ThreadPlacement> {
        let var = |name: &str| std::env::var_os(name).map(|v| v.into_string().map_err(|_| Error::arg(format!("{name} is not text")))).transpose();
        self.with_settings(var(CPUS_VARIABLE)?.as_deref(), var(PRIORITY_VARIABLE)?.as_deref())
    }

    /// This placement with a CPU list and a priority, as the variables
    /// give them, in place of its own where given.
    fn with_settings(mut self, cpus: Option<&str>, priority: Option<&str>) -> Result<ThreadPlacement> {
        if let Some(v) = cpus {
            self.cpus = Some(parse_cpu_list(v).map_err(|e| Error::arg(format!("{CPUS_VARIABLE}: {e}")))?);
        }
        if let Some(v) = priority {
            self.priority = Priority::parse(v).map_err(|e| Error::arg(format!("{PRIORITY_VARIABLE}: {e}")))?;
        }
        Ok(self)
    }

    /// Refuses what cannot be applied: CPUs that the calling thread may not
    /// run on (its own set bounds what its threads may take), or any
    /// placement on a system without these controls.
    pub fn check(&self) -> Result<()> {
        if *self == ThreadPlacement::default() {
            return Ok(());
        }
        if !cfg!(target_os = "linux") {
            return Err(Error::arg("the encoder's CPUs and priority can be set on Linux only"));
        }
        if let Some(cpus) = &self.cpus {
            if cpus.is_empty() {
                return Err(Error::arg("the encoder's CPU list is empty"));
            }
            if let Some(allowed) = allowed_cpus() {
                if let Some(c) = cpus.iter().find(|c| !allowed.contains(c)) {
                    return Err(Error::arg(format!(
                        "the encoder's CPUs name CPU {c}, which this process may not run on (it may run on {})",
                        format_cpu_list(&allowed)
                    )));
                }
            }
        }
        Ok(())
    }

    /// Applies the placement to the calling thread (and to nothing else).
    pub fn apply(&self) -> Result<()> {
        #[cfg(target_os = "linux")]
        {
            if let Some(cpus) = &self.cpus {
                // SAFETY: a zeroed cpu_set_t is an empty set; CPU_SET writes
                // within it for every CPU below CPU_SETSIZE.
                let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
                for &c in cpus {
                    if c >= libc::CPU_SETSIZE as usize {
                        return Err(Error::arg(format!("CPU {c} is past the {} this system's calls can name", libc::CPU_SETSIZE)));
                    }
                    unsafe { libc::CPU_SET(c, &mut set) };
                }
                // SAFETY: pid 0 is the calling thread; `set` is a valid set of its size.
                if unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) } != 0 {
                    return Err(Error::arg(format!("cannot run the encoder's threads on CPUs {}: {}", format_cpu_list(cpus), std::io::Error::last_os_error())));
                }
            }
            match self.priority {
                Priority::Normal => {}
                Priority::Low => {
                    // Nice values are per thread on Linux: this thread's id.
                    // SAFETY: plain system calls on the calling thread.
                    let tid = unsafe { libc::gettid() };
                    if unsafe { libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, 19) } != 0 {
                        return Err(Error::arg(format!("cannot lower the encoder's priority: {}", std::io::Error::last_os_error())));
                    }
                }
                Priority::Idle => {
                    let param = libc::sched_param { sched_priority: 0 };
                    // SAFETY: pid 0 is the calling thread; `param` is valid for SCHED_IDLE.
                    if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } != 0 {
                        return Err(Error::arg(format!("cannot give the encoder idle priority: {}", std::io::Error::last_os_error())));
                    }
                }
            }
            Ok(())
        }
        #[cfg(not(target_os = "linux"))]
        {
            self.check()
        }
    }

    /// A warning for an encoder about to share its only CPU with the
    /// thread that starts it (a rank bound to one core), where that
    /// thread's set holds one CPU and the placement names none.
    pub fn shared_cpu_warning(&self) -> Option<String> {
        if self.cpus.is_some() || self.priority != Priority::Normal {
            return None;
        }
        let allowed = allowed_cpus()?;
        (allowed.len() == 1).then(|| {
            format!(
                "this thread may run on CPU {} only (a rank bound to one core?): the encoder's threads share it with the solver; \
                 give the rank more cores and name some in {CPUS_VARIABLE} (or the encoder's CPU list), or set {PRIORITY_VARIABLE}=idle",
                allowed[0]
            )
        })
    }
}

/// The CPUs the calling thread may run on, ascending (Linux); `None` where
/// that is not known.
pub fn allowed_cpus() -> Option<Vec<usize>> {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: a zeroed cpu_set_t is an empty set, filled by the call;
        // CPU_ISSET reads within it.
        let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
        if unsafe { libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) } != 0 {
            return None;
        }
        Some((0..libc::CPU_SETSIZE as usize).filter(|&c| unsafe { libc::CPU_ISSET(c, &set) }).collect())
    }
    #[cfg(not(target_os = "linux"))]
    {
        None
    }
}

/// A CPU list as `taskset` and cpusets write it (`0-3,8,10-11`): ascending,
/// without repeats. An entry that starts with `@` names positions in the
/// calling thread's own set, from 0 (`@1` its second CPU, `@1-3` its second
/// to fourth), so that one setting serves every rank of a job whose ranks
/// are each bound to CPUs of their own (`GSENC_ENCODER_CPUS=@1` under
/// `srun -c 2`: each encoder on its rank's second CPU).
pub fn parse_cpu_list(s: &str) -> Result<Vec<usize>> {
    parse_cpu_list_in(s, allowed_cpus().as_deref())
}

/// [`parse_cpu_list`] with `own` as the calling thread's set.
fn parse_cpu_list_in(s: &str, own: Option<&[usize]>) -> Result<Vec<usize>> {
    let number = |t: &str| -> Result<usize> {
        let t = t.trim();
        let n: usize = t.parse().map_err(|_| Error::arg(format!("'{t}' is not a CPU number")))?;
        if n >= MAX_CPUS {
            return Err(Error::arg(format!("CPU {n} is past the last this library can name ({})", MAX_CPUS - 1)));
        }
        Ok(n)
    };
    let mut cpus = vec![];
    for part in s.split(',') {
        let part = part.trim();
        if part.is_empty() {
            return Err(Error::arg(format!("'{s}' has an empty entry (a list is like 0-3,8,10-11, or @1 for this thread's second CPU)")));
        }
        let (relative, range) = match part.strip_prefix('@') {
            Some(r) => (true, r),
            None => (false, part),
        };
        let (a, b) = match range.split_once('-') {
            Some((a, b)) => (number(a)?, number(b)?),
            None => (number(range)?, number(range)?),
        };
        if a > b {
            return Err(Error::arg(format!("range {a}-{b} runs backwards")));
        }
        if relative {
            let Some(own) = own else {
                return Err(Error::arg(format!("'{part}' names CPUs by position in this thread's set, which this system does not tell")));
            };
            if b >= own.len() {
                return Err(Error::arg(format!(
                    "'{part}' names position {b} of this thread's CPUs, which are {} ({}; positions from 0)",
                    own.len(),
                    format_cpu_list(own)
                )));
            }
            cpus.extend_from_slice(&own[a..=b]);
        } else {
            cpus.extend(a..=b);
        }
    }
    cpus.sort_unstable();
    cpus.dedup();
    Ok(cpus)
}

/// `cpus` (ascending) as a list of ranges.
pub fn format_cpu_list(cpus: &[usize]) -> String {
    let mut out: Vec<String> = vec![];
    let mut i = 0;
    while i < cpus.len() {
        let mut j = i;
        while j + 1 < cpus.len() && cpus[j + 1] == cpus[j] + 1 {
            j += 1;
        }
        out.push(if j > i { format!("{}-{}", cpus[i], cpus[j]) } else { cpus[i].to_string() });
        i = j + 1;
    }
    out.join(",")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists_read_as_taskset_writes_them() {
        assert_eq!(parse_cpu_list("0-3,8,10-11").unwrap(), vec![0, 1, 2, 3, 8, 10, 11]);
        assert_eq!(parse_cpu_list(" 5 , 2-3,3 ").unwrap(), vec![2, 3, 5]);
        assert_eq!(parse_cpu_list("7").unwrap(), vec![7]);
        for bad in ["", "1,", ",1", "a", "3-1", "1-", "-2", "1-2-3", "65536", "0-99999999999999999999"] {
            assert!(parse_cpu_list(bad).is_err(), "'{bad}' was read");
        }
        for cpus in [vec![0, 1, 2, 3, 8, 10, 11], vec![4], vec![0, 2, 4], vec![]] {
            assert_eq!(parse_cpu_list(&format_cpu_list(&cpus)).unwrap_or_default(), cpus);
        }
        assert_eq!(format_cpu_list(&[0, 1, 2, 3, 8, 10, 11]), "0-3,8,10-11");
    }

    /// `@` entries are positions in the calling thread's own set.
    #[test]
    fn at_entries_are_positions_in_the_threads_own_set() {
        let own = [4, 5, 9, 12];
        assert_eq!(parse_cpu_list_in("@1", Some(&own)).unwrap(), vec![5]);
        assert_eq!(parse_cpu_list_in("@1-2, 0", Some(&own)).unwrap(), vec![0, 5, 9]);
        assert_eq!(parse_cpu_list_in("@0-3", Some(&own)).unwrap(), own.to_vec());
        let e = parse_cpu_list_in("@4", Some(&own)).unwrap_err().to_string();
        assert!(e.contains("position 4") && e.contains("4-5,9,12"), "{e}");
        for bad in ["@", "@-1", "@2-1", "@x", "1@"] {
            assert!(parse_cpu_list_in(bad, Some(&own)).is_err(), "'{bad}' was read");
        }
        assert!(parse_cpu_list_in("@0", None).is_err());
        assert_eq!(parse_cpu_list_in("3", None).unwrap(), vec![3]);
        #[cfg(target_os = "linux")]
        assert_eq!(parse_cpu_list("@0").unwrap(), vec![allowed_cpus().unwrap()[0]]);
    }

    /// The variables override the configuration, each only where set, and
    /// a bad value is an error that names its variable.
    #[test]
    fn the_variables_override_the_configuration() {
        let config = ThreadPlacement { cpus: Some(vec![1]), priority: Priority::Low };
        assert_eq!(config.clone().with_settings(None, None).unwrap(), config);
        assert_eq!(config.clone().with_settings(Some("2-3"), None).unwrap(), ThreadPlacement { cpus: Some(vec![2, 3]), priority: Priority::Low });
        assert_eq!(config.clone().with_settings(None, Some("idle")).unwrap(), ThreadPlacement { cpus: Some(vec![1]), priority: Priority::Idle });
        assert!(config.clone().with_settings(Some("2-"), None).unwrap_err().to_string().contains(CPUS_VARIABLE));
        assert!(config.with_settings(None, Some("urgent")).unwrap_err().to_string().contains(PRIORITY_VARIABLE));
    }

    #[test]
    fn priorities_read_by_name() {
        assert_eq!(Priority::parse("Idle").unwrap(), Priority::Idle);
        assert_eq!(Priority::parse(" low").unwrap(), Priority::Low);
        assert_eq!(Priority::parse("normal").unwrap(), Priority::Normal);
        assert!(Priority::parse("high").is_err());
    }

    /// CPUs the process may not run on are refused before any thread
    /// starts, naming the CPU and the set it may use.
    #[cfg(target_os = "linux")]
    #[test]
    fn cpus_outside_the_callers_set_are_refused() {
        let allowed = allowed_cpus().unwrap();
        assert!(!allowed.is_empty());
        assert!(ThreadPlacement { cpus: Some(allowed.clone()), priority: Priority::Idle }.check().is_ok());
        let outside = allowed.last().unwrap() + 1;
        let e = ThreadPlacement { cpus: Some(vec![outside]), ..Default::default() }.check().unwrap_err().to_string();
        assert!(e.contains(&format!("CPU {outside}")) && e.contains(&format_cpu_list(&allowed)), "{e}");
        assert!(ThreadPlacement { cpus: Some(vec![]), ..Default::default() }.check().is_err());
    }

    /// A thread that applies a placement runs where and as it says, read
    /// back from the kernel (`/proc/thread-self`); the thread that started
    /// it is untouched.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_placement_applies_to_the_calling_thread_only() {
        let allowed = allowed_cpus().unwrap();
        let one = *allowed.last().unwrap();
        let before = std::fs::read_to_string("/proc/thread-self/status").unwrap();
        for priority in [Priority::Low, Priority::Idle] {
            let p = ThreadPlacement { cpus: Some(vec![one]), priority };
            let (cpus, policy, nice) = std::thread::spawn(move || {
                p.apply().unwrap();
                // SAFETY: plain queries of the calling thread.
                let policy = unsafe { libc::sched_getscheduler(0) };
                let nice = unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t) };
                (allowed_cpus().unwrap(), policy, nice)
            })
            .join()
            .unwrap();
            assert_eq!(cpus, vec![one], "{priority:?}");
            match priority {
                Priority::Low => assert_eq!((policy, nice), (libc::SCHED_OTHER, 19)),
                _ => assert_eq!(policy, libc::SCHED_IDLE),
            }
        }
        assert_eq!(allowed_cpus().unwrap(), allowed, "the calling thread's set changed");
        // SAFETY: a plain query of the calling thread.
        assert_eq!(unsafe { libc::sched_getscheduler(0) }, libc::SCHED_OTHER);
        let cpus_line = |s: &str| s.lines().find(|l| l.starts_with("Cpus_allowed_list")).map(str::to_owned);
        assert_eq!(cpus_line(&std::fs::read_to_string("/proc/thread-self/status").unwrap()), cpus_line(&before));
    }

    /// The warning for a caller bound to one CPU names it and the way out;
    /// a placement that says where or how the encoder runs needs none.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_caller_bound_to_one_cpu_is_warned() {
        let one = *allowed_cpus().unwrap().first().unwrap();
        let (bound, named, idle) = std::thread::spawn(move || {
            ThreadPlacement { cpus: Some(vec![one]), priority: Priority::Normal }.apply().unwrap();
            let named = ThreadPlacement { cpus: Some(vec![one]), priority: Priority::Normal }.shared_cpu_warning();
            let idle = ThreadPlacement { cpus: None, priority: Priority::Idle }.shared_cpu_warning();
            (ThreadPlacement::default().shared_cpu_warning(), named, idle)
        })
        .join()
        .unwrap();
        let w = bound.expect("no warning for a thread bound to one CPU");
        assert!(w.contains(&format!("CPU {one} only")) && w.contains(CPUS_VARIABLE) && w.contains(PRIORITY_VARIABLE), "{w}");
        assert_eq!((named, idle), (None, None));
        if allowed_cpus().unwrap().len() > 1 {
            assert_eq!(ThreadPlacement::default().shared_cpu_warning(), None);
        }
    }
}
