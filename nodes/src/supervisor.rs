//! Starts a launch file's nodes as processes ([`oilfilm_graph::launch::read`] says which,
//! with their `--ros-args`), watches them, and stops them all (SIGINT, then SIGKILL after a
//! grace period) when one dies, when asked, or at the end.
//!
//! A node also stops when its launcher dies without stopping it (SIGKILL, a crash): each
//! is started with the parent-death signal SIGTERM (Linux `prctl(PR_SET_PDEATHSIG)`), which
//! it handles as it handles SIGINT, so the exciter ramps to zero and the recorder closes
//! its bag, as `ros2 launch` stops its nodes.

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use oilfilm_graph::launch::NodeLaunch;
use oilfilm_graph::NodeError;

/// The running nodes.
pub struct Supervisor {
    children: Vec<(NodeLaunch, Child)>,
    reported: Vec<String>,
}

impl Supervisor {
    /// Starts each node from `bin_dir` with its arguments plus `extra_args` (e.g.
    /// `-p duration_s:=10` for the DAQ is added by the caller through the launch entries).
    pub fn start(nodes: &[NodeLaunch], bin_dir: &Path) -> Result<Self, NodeError> {
        let mut s = Self { children: Vec::new(), reported: Vec::new() };
        for n in nodes {
            let exe = bin_dir.join(&n.exec);
            let mut command = Command::new(&exe);
            command.args(&n.args);
            let launcher = std::process::id() as libc::pid_t;
            // SAFETY: between fork and exec the closure calls only async-signal-safe
            // functions (prctl, getppid, _exit) and allocates nothing.
            unsafe {
                command.pre_exec(move || {
                    if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong, 0, 0, 0) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    // The launcher died before the signal was armed: it will never come.
                    if libc::getppid() != launcher {
                        libc::_exit(1);
                    }
                    Ok(())
                })
            };
            match command.spawn() {
                Ok(child) => s.children.push((n.clone(), child)),
                Err(e) => {
                    s.stop(Duration::from_secs(2));
                    return Err(NodeError::Io { what: format!("starting {} ({})", n.name, exe.display()), source: e });
                }
            }
        }
        Ok(s)
    }

    /// A node that has exited since the last call, with its status (each reported once).
    pub fn exited(&mut self) -> Option<(String, std::process::ExitStatus)> {
        for (n, c) in &mut self.children {
            if self.reported.contains(&n.name) {
                continue;
            }
            if let Ok(Some(status)) = c.try_wait() {
                self.reported.push(n.name.clone());
                return Some((n.name.clone(), status));
            }
        }
        None
    }

    /// SIGINT to every node still running, then SIGKILL after `grace`.
    pub fn stop(&mut self, grace: Duration) {
        for (_, c) in &mut self.children {
            if let Ok(None) = c.try_wait() {
                // SAFETY: kill(2) on our own child's pid, which `try_wait` just saw running
                // and which we have not reaped, so the pid is still ours.
                unsafe { libc::kill(c.id() as libc::pid_t, libc::SIGINT) };
            }
        }
        let deadline = Instant::now() + grace;
        for (n, c) in &mut self.children {
            loop {
                match c.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
                    _ => {
                        tracing::warn!("{} did not stop within {grace:?}: killed", n.name);
                        let _ = c.kill();
                        let _ = c.wait();
                        break;
                    }
                }
            }
        }
    }

    /// Names of the nodes.
    pub fn names(&self) -> Vec<String> {
        self.children.iter().map(|(n, _)| n.name.clone()).collect()
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(3));
    }
}
