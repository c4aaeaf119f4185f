//! Error-against-time reports: metrics of snapshots against a reference, the CSV table, the log–log
//! plot and the HTML page with images and error maps. Nothing here knows any integrator: everything
//! arrives through `render::Snapshot` and `RenderOutput`, so new techniques appear without changes.

pub mod html;
pub mod metrics;
pub mod plot;

use anyhow::Context;
use std::io::Write;
use std::path::Path;
use std::time::Duration;

pub use metrics::{ErrorMetrics, Metric, DEFAULT_REL_EPSILON};

/// One line of `error.csv`: an integrator's image at one moment compared with the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorRow {
    pub integrator: String,
    pub elapsed: Duration,
    /// Camera samples (pixel integrators) or mutations (Metropolis).
    pub samples: u64,
    pub spp: u32,
    pub metrics: ErrorMetrics,
    /// Metropolis acceptance rate when the integrator reports one.
    pub acceptance_rate: Option<f64>,
}

/// Column names of `error.csv`, in order.
pub const CSV_HEADER: &str = "integrator,elapsed_seconds,samples,spp,rel_mse,rmse,mae,acceptance_rate";

/// The CSV table (header and one line per row); acceptance is empty where not reported.
pub fn error_csv(rows: &[ErrorRow]) -> String {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for r in rows {
        s.push_str(&format!(
            "{},{:.6},{},{},{:.6e},{:.6e},{:.6e},{}\n",
            csv_field(&r.integrator),
            r.elapsed.as_secs_f64(),
            r.samples,
            r.spp,
            r.metrics.rel_mse,
            r.metrics.rmse,
            r.metrics.mae,
            r.acceptance_rate.map(|a| format!("{a:.6}")).unwrap_or_default()
        ));
    }
    s
}

/// Quotes a CSV field when it holds a separator, a quote or a line break (RFC 4180).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The acceptance rate among an integrator's statistics: the first key ending in `acceptance_rate`
/// whose value is a number in [0, 1] (see `render::Snapshot::extra`).
pub fn acceptance_rate(stats: &[(String, String)]) -> Option<f64> {
    stats
        .iter()
        // Snapshots carry `acceptance_rate`; a finished Metropolis render's metadata `hslt.mlt.acceptance`.
        .filter(|(k, _)| k.ends_with("acceptance_rate") || k == "hslt.mlt.acceptance")
        .find_map(|(_, v)| v.trim().parse::<f64>().ok().filter(|a| (0.0..=1.0).contains(a)))
}

/// `count` times from `total`/100 to `total`, equally spaced in log time, so a log–log plot gets
/// evenly spread points (the first a hundredth of the budget: long enough for one pass or batch).
pub fn log_spaced_times(total: Duration, count: usize) -> Vec<Duration> {
    let end = total.as_secs_f64();
    let start = (end / 100.0).max(1e-3).min(end);
    match count {
        0 => Vec::new(),
        1 => vec![total],
        n => (0..n)
            .map(|i| {
                let f = i as f64 / (n - 1) as f64;
                Duration::from_secs_f64(start * (end / start).powf(f))
            })
            .collect(),
    }
}

/// A file-name stem for an integrator name (`hslt+mlt` → `hslt_mlt`): letters, digits, `-` and `_`.
pub fn file_stem(integrator: &str) -> String {
    integrator.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect()
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed to disk, then
/// renamed over the target, so a reader never sees a half-written report.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().with_context(|| format!("{}: not a file path", path.display()))?;
    let tmp = dir.join(format!(".{}.tmp-{}", name.to_string_lossy(), std::process::id()));
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_spaced_times_span_two_decades_evenly() {
        let t = log_spaced_times(Duration::from_secs(300), 5);
        assert_eq!(t.len(), 5);
        assert!((t[0].as_secs_f64() - 3.0).abs() < 1e-9);
        assert!((t[4].as_secs_f64() - 300.0).abs() < 1e-9);
        for w in t.windows(2) {
            assert!((w[1].as_secs_f64() / w[0].as_secs_f64() - 10f64.sqrt()).abs() < 1e-9);
        }
    }

    #[test]
    fn acceptance_rate_is_read_from_a_suffixed_key_and_checked() {
        let stats =
            |k: &str, v: &str| vec![("other".to_string(), "3".to_string()), (k.to_string(), v.to_string())];
        assert_eq!(acceptance_rate(&stats("hslt.acceptance_rate", "0.25")), Some(0.25));
        assert_eq!(acceptance_rate(&stats("acceptance_rate", "1.5")), None);
        assert_eq!(acceptance_rate(&stats("rate", "0.5")), None);
    }

    #[test]
    fn csv_has_one_line_per_row_and_empty_acceptance_when_unknown() {
        let row = |name: &str, acc| ErrorRow {
            integrator: name.into(),
            elapsed: Duration::from_millis(1500),
            samples: 10,
            spp: 1,
            metrics: ErrorMetrics { rel_mse: 0.5, rmse: 0.25, mae: 0.125 },
            acceptance_rate: acc,
        };
        let csv = error_csv(&[row("pt", None), row("a,b", Some(0.5))]);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], CSV_HEADER);
        assert_eq!(lines[1], "pt,1.500000,10,1,5.000000e-1,2.500000e-1,1.250000e-1,");
        assert!(lines[2].starts_with("\"a,b\",") && lines[2].ends_with(",0.500000"), "{}", lines[2]);
    }

    #[test]
    fn atomic_write_replaces_the_file_and_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("hslt-report-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.csv");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        let err = write_atomic(&dir.join("missing/a.csv"), b"x").unwrap_err();
        assert!(format!("{err:#}").contains("missing/a.csv"), "{err:#}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
