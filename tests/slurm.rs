//! The Slurm recipe of scripts/slurm run for real: a one-node cluster on loopback (Debian's
//! slurm-wlm and munge, started by scripts/slurm/local-cluster.sh), an array job of three parts and a
//! merge job that waits for them, and the merged image compared with the single-machine render.
//!
//! It needs root (slurmd runs the jobs) and the two packages. Where they are missing it says so and
//! passes, unless HSLT_REQUIRE_SLURM=1 (set by .ci/run, which installs them) makes that a failure.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Why this machine cannot run a local Slurm cluster, if it cannot.
fn missing() -> Option<String> {
    for tool in ["munged", "mungekey", "slurmctld", "slurmd", "sbatch", "squeue"] {
        let found = Command::new("sh").args(["-c", &format!("command -v {tool}")]).output();
        if !found.is_ok_and(|o| o.status.success()) {
            return Some(format!("{tool} is not installed (apt-get install slurm-wlm munge)"));
        }
    }
    let uid = Command::new("id").arg("-u").output().ok()?;
    if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
        return Some("slurmd must run as root".into());
    }
    None
}

/// Stops the cluster when the test ends, however it ends.
struct Cluster(PathBuf);

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(root().join("scripts/slurm/local-cluster.sh")).arg("stop").arg(&self.0).status();
    }
}

fn job_state(conf: &Path, job: &str) -> String {
    let out = Command::new("scontrol").args(["show", "job", job]).env("SLURM_CONF", conf).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    text.split_whitespace().find_map(|w| w.strip_prefix("JobState=")).unwrap_or("UNKNOWN").to_string()
}

#[test]
fn three_parts_on_slurm_merge_to_the_single_machine_render() {
    if let Some(why) = missing() {
        assert!(std::env::var("HSLT_REQUIRE_SLURM").as_deref() != Ok("1"), "HSLT_REQUIRE_SLURM=1 but {why}");
        eprintln!("skipped: {why}");
        return;
    }
    let dir = std::env::temp_dir().join(format!("hslt-slurm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cluster_dir = dir.join("cluster");
    let start = Command::new(root().join("scripts/slurm/local-cluster.sh"))
        .arg("start")
        .arg(&cluster_dir)
        .output()
        .unwrap();
    let _cluster = Cluster(cluster_dir.clone());
    assert!(start.status.success(), "the cluster did not start: {}", String::from_utf8_lossy(&start.stderr));
    let conf = cluster_dir.join("slurm.conf");

    let hslt = env!("CARGO_BIN_EXE_hslt");
    let scene = root().join("scenes/cornell-box/scene.xml");
    let render_opts = ["-D", "resx=40", "-D", "resy=30", "--spp", "12", "--seed", "5"];
    let (jobs, merged) = (dir.join("jobs"), dir.join("merged.exr"));
    let submit = Command::new(root().join("scripts/slurm/submit.sh"))
        .args(["-n", "3", "-d"])
        .arg(&jobs)
        .arg("-o")
        .arg(&merged)
        .arg(&scene)
        .args(render_opts)
        .env("SLURM_CONF", &conf)
        .env("HSLT", hslt)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&submit.stdout).into_owned();
    assert!(submit.status.success(), "submit failed: {said} {}", String::from_utf8_lossy(&submit.stderr));
    let merge_job =
        said.split("merge: job ").nth(1).and_then(|r| r.split_whitespace().next()).unwrap().to_string();

    let started = Instant::now();
    loop {
        let state = job_state(&conf, &merge_job);
        if state == "COMPLETED" {
            break;
        }
        let log = |name: &str| std::fs::read_to_string(jobs.join(name)).unwrap_or_default();
        assert!(
            !matches!(state.as_str(), "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL" | "OUT_OF_MEMORY"),
            "merge job {state}: {} {} {}",
            log("merge.log"),
            log("part_1.log"),
            log("part_2.log")
        );
        assert!(
            started.elapsed() < Duration::from_secs(240),
            "the jobs did not finish in 240 s (merge job {state})"
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    for k in 1..=3 {
        assert!(jobs.join(format!("part_{k}.exr")).is_file(), "part {k} missing");
    }
    let single = dir.join("single.exr");
    let out = Command::new(hslt)
        .arg("render")
        .arg(&scene)
        .args(render_opts)
        .args(["-q", "-o"])
        .arg(&single)
        .output()
        .unwrap();
    assert!(out.status.success());
    let (a, b) =
        (hslt::image::read_image(&merged, false).unwrap(), hslt::image::read_image(&single, false).unwrap());
    let err = hslt::report::metrics::compute(&a, &b, 1e-2).unwrap().rel_mse;
    assert!(err <= 1e-6, "merged Slurm parts against the single render: rel MSE {err:e}");
    let meta = hslt::image::read_exr_metadata(&merged).unwrap();
    assert!(meta.iter().any(|(k, v)| k == "hslt.part.covers" && v == "1,2,3"), "{meta:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
