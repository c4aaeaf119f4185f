//! What this process may still allocate, so that loaders can refuse an input whose declared size (a
//! film, an image header) cannot fit, with an error naming it, instead of aborting on a failed
//! allocation or being killed by the kernel: the smaller of the system's available memory plus free
//! swap (/proc/meminfo) and what an address-space limit (`ulimit -v`, /proc/self/limits) leaves.

const GIB: f64 = (1u64 << 30) as f64;

/// Bytes this process can still allocate, or `None` where Linux's /proc is not there to say.
pub fn memory_budget() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let system = meminfo.as_deref().and_then(|m| {
        let available = kib_field(m, "MemAvailable:")?;
        Some(available + kib_field(m, "SwapFree:").unwrap_or(0))
    });
    let address_space = address_space_left();
    match (system, address_space) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// Checks that `bytes` more fit in `memory_budget()`; the error says what needed them, in GiB.
pub fn check_fits(bytes: u64, what: &str) -> Result<(), String> {
    match memory_budget() {
        Some(budget) if bytes > budget => Err(too_large(bytes, budget, what)),
        _ => Ok(()),
    }
}

fn too_large(bytes: u64, budget: u64, what: &str) -> String {
    format!(
        "{what} needs {:.1} GiB, more than the {:.1} GiB this process can still allocate",
        bytes as f64 / GIB,
        budget as f64 / GIB
    )
}

/// A `Vec` of `len` copies of `value`, or an error instead of the abort a failed allocation causes.
pub fn try_filled_vec<T: Clone>(len: usize, value: T, what: &str) -> Result<Vec<T>, String> {
    let bytes = (len as u64).saturating_mul(std::mem::size_of::<T>() as u64);
    check_fits(bytes, what)?;
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| too_large(bytes, memory_budget().unwrap_or(0), what))?;
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
}
