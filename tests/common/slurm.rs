//! A real single-node Slurm for the tests, started as root in a temporary folder from Debian's
//! packages (`slurm-wlm`, `munge`; `make slurm-deps` installs them). No systemd: `munged`,
//! `slurmctld -i` and `slurmd` are started by hand with `SLURM_CONF` pointing at a generated
//! `slurm.conf`, on free ports, and stopped by their pid files when the `Cluster` is dropped.
//! `sched_interval=1,bf_interval=1` makes a chain of dependent jobs finish in seconds.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

pub struct Cluster {
    pub dir: tempfile::TempDir,
    pub conf: PathBuf,
}

/// Where Debian puts a Slurm or munge program (root's PATH has /usr/sbin, a test's may not).
fn program(name: &str) -> Option<PathBuf> {
    let dirs = std::env::var("PATH").unwrap_or_default();
    let mut candidates: Vec<PathBuf> = std::env::split_paths(&dirs).map(|d| d.join(name)).collect();
    candidates.extend(["/usr/sbin", "/usr/bin", "/sbin"].iter().map(|d| Path::new(d).join(name)));
    candidates.into_iter().find(|p| p.is_file())
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// Starts a cluster, or says plainly on stderr why `test` is skipped and returns None: not root
/// (slurmd must be), or the packages are missing. A cluster that is installed but does not
/// start is a failure, not a skip.
pub fn cluster(test: &str) -> Option<Cluster> {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("SKIPPED {test}: a test Slurm must be started as root (slurmd runs jobs as their users)");
        return None;
    }
    let missing: Vec<&str> = ["munged", "slurmctld", "slurmd", "sbatch", "squeue", "srun"]
        .into_iter()
        .filter(|p| program(p).is_none())
        .collect();
    if !missing.is_empty() {
        eprintln!(
            "SKIPPED {test}: no Slurm here ({} not found); `make slurm-deps` installs slurm-wlm and munge as root",
            missing.join(", ")
        );
        return None;
    }
    Some(Cluster::start())
}

impl Cluster {
    fn start() -> Cluster {
        let started = Instant::now();
        let dir = tempfile::Builder::new().prefix("pgser-slurm-").tempdir().unwrap();
        let d = dir.path();
        for sub in ["state", "spool"] {
            std::fs::create_dir(d.join(sub)).unwrap();
        }
        // munge: a key of our own, 0600, and a socket in our folder.
        let mut bytes = vec![0u8; 1024];
        std::io::Read::read_exact(&mut std::fs::File::open("/dev/urandom").unwrap(), &mut bytes).unwrap();
        std::fs::write(d.join("munge.key"), bytes).unwrap();
        std::fs::set_permissions(d.join("munge.key"), std::os::unix::fs::PermissionsExt::from_mode(0o600)).unwrap();
        let socket = d.join("munge.socket");
        let munged = Command::new(program("munged").unwrap())
            .arg("--force")
            .arg("-S")
            .arg(&socket)
            .arg(format!("--key-file={}", d.join("munge.key").display()))
            .arg(format!("--pid-file={}", d.join("munged.pid").display()))
            .arg(format!("--log-file={}", d.join("munged.log").display()))
            .arg(format!("--seed-file={}", d.join("munged.seed").display()))
            .output()
            .unwrap();
        let c = Cluster { conf: d.join("slurm.conf"), dir };
        assert!(munged.status.success(), "munged did not start: {}{}", super::text(&munged.stderr), c.logs());
        let d = c.dir.path();
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap().trim().to_string();
        let cpus = std::thread::available_parallelism().unwrap().get();
        let conf = format!(
            "ClusterName=pgsertest\n\
             SlurmctldHost={host}(127.0.0.1)\n\
             SlurmctldPort={ctld}\n\
             SlurmdPort={slurmd}\n\
             SlurmUser=root\n\
             SlurmdUser=root\n\
             AuthType=auth/munge\n\
             CredType=cred/munge\n\
             AuthInfo=socket={socket}\n\
             StateSaveLocation={d}/state\n\
             SlurmdSpoolDir={d}/spool\n\
             SlurmctldPidFile={d}/slurmctld.pid\n\
             SlurmdPidFile={d}/slurmd.pid\n\
             SlurmctldLogFile={d}/slurmctld.log\n\
             SlurmdLogFile={d}/slurmd.log\n\
             ProctrackType=proctrack/linuxproc\n\
             TaskPlugin=task/none\n\
             JobAcctGatherType=jobacct_gather/none\n\
             AccountingStorageType=accounting_storage/none\n\
             JobCompType=jobcomp/none\n\
             SchedulerType=sched/backfill\n\
             SchedulerParameters=sched_interval=1,bf_interval=1\n\
             SelectType=select/cons_tres\n\
             SelectTypeParameters=CR_Core\n\
             SlurmdParameters=config_overrides\n\
             ReturnToService=2\n\
             MpiDefault=none\n\
             InactiveLimit=0\n\
             KillWait=10\n\
             NodeName=pgsernode NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN\n\
             PartitionName=test Nodes=pgsernode Default=YES MaxTime=INFINITE State=UP\n",
            ctld = free_port(),
            slurmd = free_port(),
            socket = socket.display(),
            d = d.display(),
        );
        std::fs::write(&c.conf, conf).unwrap();
        for (daemon, args) in [("slurmctld", &["-i"][..]), ("slurmd", &["-N", "pgsernode"][..])] {
            let o = c.command(daemon).args(args).output().unwrap();
            assert!(o.status.success(), "{daemon} did not start: {}{}", super::text(&o.stderr), c.logs());
        }
        // Ready when the node is idle.
        let t0 = Instant::now();
        loop {
            let o = c.command("sinfo").args(["--noheader", "--format=%T"]).output().unwrap();
            if super::text(&o.stdout).trim() == "idle" {
                eprintln!("the test Slurm was up in {:.1} s", started.elapsed().as_secs_f64());
                break c;
            }
            assert!(t0.elapsed() < Duration::from_secs(60), "the test Slurm's node never became idle{}", c.logs());
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// A Slurm program of this cluster (`SLURM_CONF` set).
    pub fn command(&self, name: &str) -> Command {
        let mut c = Command::new(program(name).unwrap_or_else(|| PathBuf::from(name)));
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// `pgser-etl` with this cluster's `SLURM_CONF`, and the Slurm programs on its PATH.
    pub fn etl(&self) -> Command {
        let mut c = super::etl();
        c.env("SLURM_CONF", &self.conf);
        let path = std::env::var("PATH").unwrap_or_default();
        c.env("PATH", format!("{path}:/usr/sbin:/usr/bin"));
        c
    }

    /// The daemons' logs, for a failure message.
    pub fn logs(&self) -> String {
        let mut s = String::new();
        for f in ["munged.log", "slurmctld.log", "slurmd.log"] {
            let text = std::fs::read_to_string(self.dir.path().join(f)).unwrap_or_default();
            let tail: Vec<&str> = text.lines().rev().take(15).collect();
            s += &format!("\n--- {f} (last lines)\n{}", tail.into_iter().rev().collect::<Vec<_>>().join("\n"));
        }
        s
    }

    /// The state of job `id` while Slurm holds it (`PENDING`, `RUNNING`, …); None once it left.
    pub fn job_state(&self, id: &str) -> Option<String> {
        let o = self.command("squeue").args(["--noheader", "--format=%T", "--jobs", id]).output().unwrap();
        let state = super::text(&o.stdout).trim().to_string();
        (o.status.success() && !state.is_empty()).then_some(state)
    }

    /// Waits until Slurm holds none of `ids` any more.
    pub fn wait_gone(&self, ids: &[String], limit: Duration) {
        let t0 = Instant::now();
        while ids.iter().any(|id| self.job_state(id).is_some()) {
            assert!(t0.elapsed() < limit, "jobs {ids:?} still queued after {limit:?}");
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // Jobs first (a failed test may leave some), then the daemons by their pid files.
        let _ = self.command("scancel").args(["--user=root", "--full"]).output();
        for pid_file in ["slurmd.pid", "slurmctld.pid", "munged.pid"] {
            let Ok(text) = std::fs::read_to_string(self.dir.path().join(pid_file)) else { continue };
            let Ok(pid) = text.trim().parse::<i32>() else { continue };
            // SAFETY: kill only sends a signal to the daemon this cluster started.
            unsafe { libc::kill(pid, libc::SIGTERM) };
            let t0 = Instant::now();
            while Path::new(&format!("/proc/{pid}")).exists() && t0.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(50));
            }
            if Path::new(&format!("/proc/{pid}")).exists() {
                // SAFETY: as above.
                unsafe { libc::kill(pid, libc::SIGKILL) };
            }
        }
    }
}
