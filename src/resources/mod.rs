//! What this process may still allocate, so that loaders can refuse an input whose declared size (a
//! film, an image header) cannot fit, with an error naming it, instead of aborting on a failed
//! allocation or being killed by the kernel: the smaller of the system's available memory plus free
//! swap (/proc/meminfo), what an address-space limit (`ulimit -v`, /proc/self/limits) leaves and
//! what the user's `--max-memory` cap leaves of resident memory; and the watch on that cap.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

const GIB: f64 = (1u64 << 30) as f64;

/// The user's cap on resident memory in bytes (`--max-memory`); 0 when none is set.
static MEMORY_CAP: AtomicU64 = AtomicU64::new(0);

/// Caps this process's resident memory: loaders refuse what would not fit under `bytes`, and
/// `resident_over_cap` tells a long render when it has grown past it.
pub fn set_memory_cap(bytes: u64) {
    MEMORY_CAP.store(bytes, Ordering::Relaxed);
}

pub fn memory_cap() -> Option<u64> {
    Some(MEMORY_CAP.load(Ordering::Relaxed)).filter(|&c| c > 0)
}

/// Which limit a budget comes from, for the error message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Limit {
    SystemMemory,
    AddressSpace,
    UserCap,
}

impl Limit {
    fn describe(self) -> &'static str {
        match self {
            Limit::SystemMemory => "this process can still allocate",
            Limit::AddressSpace => "the address-space limit (ulimit -v) leaves",
            Limit::UserCap => "--max-memory leaves",
        }
    }
}

/// Bytes this process can still allocate, or `None` where Linux's /proc is not there to say (and no
/// cap is set).
pub fn memory_budget() -> Option<u64> {
    budget_and_limit().map(|(b, _)| b)
}

fn budget_and_limit() -> Option<(u64, Limit)> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let system = meminfo.as_deref().and_then(|m| {
        let available = kib_field(m, "MemAvailable:")?;
        Some((available + kib_field(m, "SwapFree:").unwrap_or(0), Limit::SystemMemory))
    });
    let address_space = address_space_left().map(|b| (b, Limit::AddressSpace));
    let cap = memory_cap().map(|cap| (cap.saturating_sub(resident_bytes().unwrap_or(0)), Limit::UserCap));
    [system, address_space, cap].into_iter().flatten().min_by_key(|&(b, _)| b)
}

/// Checks that `bytes` more fit in `memory_budget()`; the error says what needed them, in GiB.
pub fn check_fits(bytes: u64, what: &str) -> Result<(), String> {
    match budget_and_limit() {
        Some((budget, limit)) if bytes > budget => Err(too_large(bytes, budget, limit, what)),
        _ => Ok(()),
    }
}

fn too_large(bytes: u64, budget: u64, limit: Limit, what: &str) -> String {
    let mut message = format!(
        "{what} needs {}, more than the {} {}",
        human_size(bytes),
        human_size(budget),
        limit.describe()
    );
    if limit == Limit::UserCap {
        if let Some(rss) = resident_bytes() {
            message += &format!(" beside the {} already resident", human_size(rss));
        }
    }
    message
}

/// The process's resident memory (VmRSS), in bytes.
pub fn resident_bytes() -> Option<u64> {
    kib_field(&std::fs::read_to_string("/proc/self/status").ok()?, "VmRSS:")
}

/// The most resident memory this process has had (VmHWM), in bytes.
pub fn peak_resident_bytes() -> Option<u64> {
    kib_field(&std::fs::read_to_string("/proc/self/status").ok()?, "VmHWM:")
}

/// CPU seconds this process has used, user and system, over all its threads (/proc/self/stat's utime
/// and stime, in USER_HZ ticks, which Linux fixes at 100 for /proc on every architecture we build for).
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: count fields after its ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // After ')' come state (field 3), ..., utime (14) and stime (15): indices 11 and 12 here.
    let ticks: u64 = fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / 100.0)
}

/// The resident memory, when a cap is set and it is over it: what a render's watchdog polls.
pub fn resident_over_cap() -> Option<(u64, u64)> {
    let cap = memory_cap()?;
    let rss = resident_bytes()?;
    (rss > cap).then_some((rss, cap))
}

/// Parses a size such as `4G`, `512MiB`, `1.5g` or `100000000` (bytes; suffixes K, M, G, T are
/// powers of 1024, with or without `i`/`iB`/`B`).
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (number, suffix) = t.split_at(split);
    let value: f64 = number.parse().map_err(|_| format!("'{text}' is not a size such as 4G or 512M"))?;
    let shift = match suffix.trim().to_ascii_uppercase().trim_end_matches('B').trim_end_matches('I') {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        _ => return Err(format!("'{text}': unknown unit '{suffix}' (use K, M, G or T)")),
    };
    let bytes = value * (1u64 << shift) as f64;
    if !(bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("'{text}' is not a positive size"));
    }
    Ok(bytes as u64)
}

/// A size for messages: MiB below a GiB, GiB with one decimal above.
pub fn human_size(bytes: u64) -> String {
    if bytes < 1 << 20 {
        format!("{:.0} KiB", (bytes as f64 / 1024.0).ceil())
    } else if (bytes as f64) < GIB {
        format!("{:.0} MiB", bytes as f64 / (1u64 << 20) as f64)
    } else {
        format!("{:.1} GiB", bytes as f64 / GIB)
    }
}

/// A `Vec` of `len` copies of `value`, or an error instead of the abort a failed allocation causes.
pub fn try_filled_vec<T: Clone>(len: usize, value: T, what: &str) -> Result<Vec<T>, String> {
    let bytes = (len as u64).saturating_mul(std::mem::size_of::<T>() as u64);
    check_fits(bytes, what)?;
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| {
        let (budget, limit) = budget_and_limit().unwrap_or((0, Limit::SystemMemory));
        too_large(bytes, budget, limit, what)
    })?;
    v.resize(len, value);
    Ok(v)
}

/// A `kB` field of /proc/meminfo or /proc/self/status, in bytes.
fn kib_field(text: &str, key: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(key))?;
    let kib: u64 = line[key.len()..].split_whitespace().next()?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// The soft address-space limit minus the address space already mapped, if a limit is set.
fn address_space_left() -> Option<u64> {
    let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = limits.lines().find(|l| l.starts_with("Max address space"))?;
    // "Max address space   <soft>   <hard>   bytes": the soft limit is what allocations hit.
    let limit: u64 = line["Max address space".len()..].split_whitespace().next()?.parse().ok()?;
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let mapped = kib_field(&status, "VmSize:").unwrap_or(0);
    Some(limit.saturating_sub(mapped))
}

/// Files the loaders read (included scene files, meshes, textures, environment maps).
static INPUT_FILES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Notes a file a loader read, so a render can record everything its image depends on (the scene
/// hash that `--part` and `--checkpoint` store and `merge` and `--resume` compare).
pub fn note_input_file(path: &Path) {
    let path = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    // A poisoned lock only means another loader panicked; the list itself is still valid.
    let mut files = INPUT_FILES.lock().unwrap_or_else(|e| e.into_inner());
    if !files.contains(&path) {
        files.push(path);
    }
}

/// The files noted so far by this process's loaders, in the order they were first read.
pub fn input_files() -> Vec<PathBuf> {
    INPUT_FILES.lock().unwrap_or_else(|e| e.into_inner()).clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_proc_fields_in_bytes() {
        let meminfo = "MemTotal:       16000000 kB\nMemAvailable:    8000000 kB\nSwapFree:  0 kB\n";
        assert_eq!(kib_field(meminfo, "MemAvailable:"), Some(8_000_000 * 1024));
        assert_eq!(kib_field(meminfo, "SwapFree:"), Some(0));
        assert_eq!(kib_field(meminfo, "Missing:"), None);
    }

    #[test]
    fn an_impossible_request_is_an_error_and_a_small_one_is_not() {
        if memory_budget().is_none() {
            return; // no /proc: nothing to check against
        }
        let err = check_fits(u64::MAX / 2, "a test buffer").unwrap_err();
        assert!(err.starts_with("a test buffer needs "), "{err}");
        assert!(check_fits(1 << 20, "a megabyte").is_ok());
        assert!(try_filled_vec(usize::MAX / 64, 0u8, "a huge vector").is_err());
        assert_eq!(try_filled_vec(4, 7u16, "four").unwrap(), vec![7; 4]);
    }

    #[test]
    fn cpu_time_grows_with_work_and_peak_memory_is_at_least_the_current() {
        let (Some(before), Some(rss)) = (cpu_seconds(), resident_bytes()) else {
            return; // no /proc
        };
        let start = std::time::Instant::now();
        let mut x = 1.0f64;
        while start.elapsed().as_secs_f64() < 0.3 {
            x = std::hint::black_box(x.sqrt() + 1.0);
        }
        let after = cpu_seconds().unwrap();
        assert!(after - before >= 0.1 && after - before < 30.0, "{before} -> {after} ({x})");
        assert!(peak_resident_bytes().unwrap() >= rss);
    }

    #[test]
    fn sizes_parse_with_binary_units() {
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("512MiB"), Ok(512 << 20));
        assert_eq!(parse_size("1.5g"), Ok(3 << 29));
        assert_eq!(parse_size("100000"), Ok(100_000));
        assert_eq!(parse_size(" 2 TB "), Ok(2 << 40));
        for bad in ["", "G", "4X", "-1G", "0", "1e400", "1.2.3M"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }
}
