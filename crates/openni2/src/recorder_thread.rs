//! The thread OpenNI2's recorder runs on, seen through Linux's `/proc`: found when the
//! recorder is created, and watched to know that it has run on past a point (see
//! [`crate::Recorder::start`]).

use std::time::{Duration, Instant};

/// CPU ticks a thread must be charged after a point for it to have run on past it: two, so
/// that it was on a CPU at two scheduler ticks (10 ms apart at 100 Hz) after that point.
pub const RUN_ON_TICKS: u64 = 2;

/// This process's threads with the calling thread's name. A new thread inherits its
/// creator's name and OpenNI2 names none of its own, so the threads that appear across a
/// call on the OpenNI2 thread are the ones that call started.
pub(crate) fn threads_named_like_this_one() -> Vec<u32> {
    let Ok(me) = std::fs::read_to_string("/proc/thread-self/comm") else {
        return Vec::new();
    };
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return Vec::new();
    };
    tasks
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|tid| {
            std::fs::read_to_string(format!("/proc/self/task/{tid}/comm")).is_ok_and(|c| c == me)
        })
        .collect()
}

/// The CPU time the scheduler has charged thread `tid` of this process (user + system,
/// clock ticks); `None` once it is gone.
fn cpu_ticks(tid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/self/task/{tid}/stat")).ok()?;
    // The name, in parentheses, may hold spaces: count the fields after it (the state is
    // field 3, utime and stime fields 14 and 15).
    let fields: Vec<&str> = stat
        .get(stat.rfind(')')? + 1..)?
        .split_whitespace()
        .collect();
    Some(fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?)
}

/// Waits until each of `threads` has been charged [`RUN_ON_TICKS`] more CPU ticks than now
/// (or has exited). False when there is no thread to watch, or `limit` passes first (a
/// thread that blocks instead of running).
pub(crate) fn ran_on(threads: &[u32], limit: Duration) -> bool {
    if threads.is_empty() {
        return false;
    }
    let start: Vec<Option<u64>> = threads.iter().map(|&t| cpu_ticks(t)).collect();
    let deadline = Instant::now() + limit;
    loop {
        let all = threads
            .iter()
            .zip(&start)
            .all(|(&t, at)| match (at, cpu_ticks(t)) {
                (Some(at), Some(now)) => now >= at + RUN_ON_TICKS,
                _ => true,
            });
        if all {
            return true;
        }
        if Instant::now() > deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{mpsc, Arc};

    fn this_tid() -> u32 {
        let link = std::fs::read_link("/proc/thread-self").unwrap();
        link.file_name().unwrap().to_str().unwrap().parse().unwrap()
    }

    /// Threads started from a named thread are found by that name; the one that spins is
    /// seen to run on, the one blocked on a channel is not (and no thread to watch is not).
    #[test]
    fn a_spinning_thread_started_here_is_found_and_seen_to_run_on() {
        std::thread::Builder::new()
            .name("mp-run-on-test".into())
            .spawn(|| {
                let before = threads_named_like_this_one();
                let stop = Arc::new(AtomicBool::new(false));
                let flag = Arc::clone(&stop);
                let (tids, tid) = mpsc::sync_channel(2);
                let to_send = tids.clone();
                let spinner = std::thread::spawn(move || {
                    to_send.send(this_tid()).unwrap();
                    while !flag.load(Ordering::Relaxed) {
                        std::hint::spin_loop();
                    }
                });
                let spinning = tid.recv().unwrap();
                let (release, wait) = mpsc::sync_channel::<()>(1);
                let blocked = std::thread::spawn(move || {
                    tids.send(this_tid()).unwrap();
                    let _ = wait.recv();
                });
                let blocking = tid.recv().unwrap();
                let mut new: Vec<u32> = threads_named_like_this_one()
                    .into_iter()
                    .filter(|t| !before.contains(t))
                    .collect();
                new.sort_unstable();
                let mut expected = vec![spinning, blocking];
                expected.sort_unstable();
                assert_eq!(new, expected);
                assert!(ran_on(&[spinning], Duration::from_secs(60)));
                assert!(!ran_on(&[blocking], Duration::from_millis(300)));
                assert!(!ran_on(&[], Duration::from_secs(1)));
                stop.store(true, Ordering::Relaxed);
                release.send(()).unwrap();
                spinner.join().unwrap();
                blocked.join().unwrap();
            })
            .unwrap()
            .join()
            .unwrap();
    }
}
