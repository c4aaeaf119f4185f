//! `hslt bench pt --mitsuba`: our whole `hslt render --integrator pt` process against Mitsuba 3 rendering
//! the same scene XML, run pair by pair in one benchmark (issue 29). Mitsuba is an optional oracle
//! reached through a Python interpreter that can import it; without one the comparison is skipped.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// The Python side: imports Mitsuba, loads the scene with the `-D` values, renders it twice with the
/// path tracer (the first render includes the LLVM variant's JIT compilation unless Dr.Jit's kernel
/// cache on disk already holds it, the second reuses the kernels) and prints one JSON line with the
/// timings and the process's peak resident memory.
const MITSUBA_SCRIPT: &str = r#"
import json, os, resource, sys, time
llvm = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
if os.path.exists(llvm):
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", llvm)
started = time.perf_counter()
import drjit as dr
import mitsuba as mi
variant, path, spp, threads, defines = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), json.loads(sys.argv[5])
mi.set_variant(variant)
if threads > 0:
    dr.set_thread_count(threads)
imported = time.perf_counter()
scene = mi.load_file(path, **defines)
loaded = time.perf_counter()
def render(seed):
    t = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t
first = render(1)
second = render(2)
size = scene.sensors()[0].film().crop_size()
def peak_memory():
    # VmHWM, as hslt reports its own: getrusage's ru_maxrss survives exec, so a child started by a
    # large process would report the parent's peak.
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"version": mi.__version__, "import_seconds": imported - started,
    "load_seconds": loaded - imported, "first_render_seconds": first, "render_seconds": second,
    "samples": int(size[0]) * int(size[1]) * spp,
    "peak_memory_bytes": peak_memory()}))
"#;

/// What one Mitsuba run reported.
#[derive(Clone, Debug)]
pub struct MitsubaRun {
    pub version: String,
    pub import_seconds: f64,
    pub load_seconds: f64,
    /// The first render: for the LLVM variants it includes compiling the kernels.
    pub first_render_seconds: f64,
    /// The second render of the same scene, with the kernels cached: the render alone.
    pub render_seconds: f64,
    pub samples: u64,
    pub peak_memory_bytes: u64,
}

/// What one run of our whole process reported.
#[derive(Clone, Debug)]
pub struct OurRun {
    /// Wall time of the whole `hslt render` process, start to exit.
    pub process_seconds: f64,
    pub samples: u64,
    pub peak_memory_bytes: u64,
}

/// The interpreter to try: `explicit`, else `$HSLT_MITSUBA_PYTHON`, else `python3`.
pub fn python_for_mitsuba(explicit: Option<&Path>) -> PathBuf {
    explicit
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os("HSLT_MITSUBA_PYTHON").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("python3"))
}

/// `Ok(version)` when `python` imports Mitsuba 3 and has `variant`, else why not.
pub fn probe(python: &Path, variant: &str) -> Result<String, String> {
    let script = format!(
        "import mitsuba as mi\nassert {variant:?} in mi.variants(), 'variant {variant} is not built'\nprint(mi.__version__)"
    );
    let out = Command::new(python)
        .args(["-c", &script])
        .output()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err.lines().last().unwrap_or("no message").trim().to_string();
        return Err(format!("{} cannot import Mitsuba 3: {last}", python.display()));
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// Renders `scene` with Mitsuba's `variant` in a child interpreter.
pub fn run_mitsuba(
    python: &Path,
    variant: &str,
    scene: &Path,
    defines: &[(String, String)],
    spp: u32,
    threads: usize,
) -> anyhow::Result<MitsubaRun> {
    let defines: serde_json::Map<String, serde_json::Value> =
        defines.iter().map(|(k, v)| (k.clone(), serde_json::Value::String(v.clone()))).collect();
    let out = Command::new(python)
        .args(["-c", MITSUBA_SCRIPT, variant])
        .arg(scene)
        .args([spp.to_string(), threads.to_string(), serde_json::Value::Object(defines).to_string()])
        .output()
        .map_err(|e| anyhow::anyhow!("cannot run {}: {e}", python.display()))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        anyhow::bail!(
            "Mitsuba ({variant}) failed on {}: {}",
            scene.display(),
            String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("no message")
        );
    }
    let line = stdout.lines().rev().find(|l| l.trim_start().starts_with('{')).unwrap_or("");
    let json: serde_json::Value = serde_json::from_str(line)
        .map_err(|e| anyhow::anyhow!("Mitsuba ({variant}) printed no result ({e}): {stdout}"))?;
    let number = |k: &str| {
        json.get(k)
            .and_then(|v| v.as_f64())
            .ok_or_else(|| anyhow::anyhow!("Mitsuba ({variant}) reported no {k}: {line}"))
    };
    Ok(MitsubaRun {
        version: json.get("version").and_then(|v| v.as_str()).unwrap_or("?").to_string(),
        import_seconds: number("import_seconds")?,
        load_seconds: number("load_seconds")?,
        first_render_seconds: number("first_render_seconds")?,
        render_seconds: number("render_seconds")?,
        samples: number("samples")? as u64,
        peak_memory_bytes: number("peak_memory_bytes")? as u64,
    })
}

/// Runs `hslt render --integrator pt` on `scene` as a child process of this executable and times it
/// from spawn to exit.
pub fn run_ours(
    scene: &Path,
    defines: &[(String, String)],
    spp: u32,
    threads: usize,
    scratch: &Path,
) -> anyhow::Result<OurRun> {
    let exe = std::env::current_exe()?;
    let (image, stats) = (scratch.join("bench-pt.exr"), scratch.join("bench-pt.json"));
    let mut cmd = Command::new(exe);
    cmd.arg("render").arg(scene);
    for (k, v) in defines {
        cmd.arg("-D").arg(format!("{k}={v}"));
    }
    cmd.args(["--integrator", "pt", "--spp", &spp.to_string(), "--seed", "1", "-q"])
        .args(["--threads", &threads.to_string()])
        .arg("-o")
        .arg(&image)
        .arg("--stats-json")
        .arg(&stats);
    let started = Instant::now();
    let out = cmd.output()?;
    let process_seconds = started.elapsed().as_secs_f64();
    if !out.status.success() {
        anyhow::bail!("hslt render failed on {}: {}", scene.display(), String::from_utf8_lossy(&out.stderr));
    }
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats)?)?;
    let field = |k: &str| json.get(k).and_then(|v| v.as_u64()).unwrap_or(0);
    Ok(OurRun { process_seconds, samples: field("samples"), peak_memory_bytes: field("peak_memory_bytes") })
}
