//! The fifteen numerically stiff and extreme cases of the HSLT method digest (§5): near-specular and
//! very rough vertices, grazing configurations, long chains, near-singular J, Newton divergence, frame
//! seams, flat shading, degenerate endpoints, index matching, kernel validation, detailed balance, scale
//! invariance, stuck chains and f32 against f64. Each case measures the robust behaviour the digest asks
//! for and judges it; `hslt stability` prints them as a table (docs/stability.md) and
//! `tests/stability.rs` asserts every verdict.

mod geometry_cases;
mod sampling_cases;
mod scenes;

/// Case 13's scene (a rough metal floor and sphere under a small light) with every length times
/// `scale`, for checks of scale invariance outside the case.
pub use sampling_cases::scale::scene_xml as scale_case_scene;

use std::fmt::Write as _;
use std::time::Instant;

/// How much work a case spends: `Quick` is what the test suite runs, `Full` what the table is made
/// with (more samples, tighter error bars; the same thresholds).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effort {
    Quick,
    Full,
}

impl Effort {
    /// `quick` in the test suite, `full` times that in the table.
    pub fn scale(self, quick: usize, full: usize) -> usize {
        match self {
            Effort::Quick => quick,
            Effort::Full => full,
        }
    }
}

/// What one case measured and whether the behaviour is the robust one.
#[derive(Clone, Debug)]
pub struct CaseReport {
    /// What was measured, with its numbers (one line of the table).
    pub measured: String,
    /// Every check of the case that failed; empty means it passed.
    pub failures: Vec<String>,
}

impl CaseReport {
    pub fn new() -> CaseReport {
        CaseReport { measured: String::new(), failures: Vec::new() }
    }

    /// Appends a measurement to the table line.
    pub fn measure(&mut self, text: impl AsRef<str>) {
        if !self.measured.is_empty() {
            self.measured.push_str("; ");
        }
        self.measured.push_str(text.as_ref());
    }

    /// Records a check: when `ok` is false the case fails with `what` as the reason.
    pub fn check(&mut self, ok: bool, what: impl Into<String>) {
        if !ok {
            self.failures.push(what.into());
        }
    }

    pub fn passed(&self) -> bool {
        self.failures.is_empty()
    }
}

impl Default for CaseReport {
    fn default() -> Self {
        CaseReport::new()
    }
}

/// One stiff case: its number in digest §5, a short name, the robust behaviour it demands and the
/// function that measures it.
pub struct Case {
    pub number: usize,
    pub name: &'static str,
    pub expected: &'static str,
    pub run: fn(Effort) -> CaseReport,
}

/// All cases, in the digest's order.
pub fn cases() -> Vec<Case> {
    let mut all = Vec::new();
    all.extend(geometry_cases::cases());
    all.extend(sampling_cases::cases());
    all.sort_by_key(|c| c.number);
    all
}

/// A case's report with its wall time.
pub struct CaseRun {
    pub number: usize,
    pub name: &'static str,
    pub expected: &'static str,
    pub report: CaseReport,
    pub seconds: f64,
}

/// Runs the cases whose numbers are in `only` (all when empty).
pub fn run(effort: Effort, only: &[usize]) -> Vec<CaseRun> {
    cases()
        .into_iter()
        .filter(|c| only.is_empty() || only.contains(&c.number))
        .map(|c| {
            let started = Instant::now();
            let report = (c.run)(effort);
            CaseRun {
                number: c.number,
                name: c.name,
                expected: c.expected,
                report,
                seconds: started.elapsed().as_secs_f64(),
            }
        })
        .collect()
}

/// The runs as a Markdown table: case, robust behaviour, measured, outcome.
pub fn table(runs: &[CaseRun]) -> String {
    let mut out =
        String::from("| # | case | robust behaviour | measured | outcome |\n|---|---|---|---|---|\n");
    for r in runs {
        let outcome = if r.report.passed() {
            format!("pass ({:.1} s)", r.seconds)
        } else {
            format!("**FAIL**: {}", r.report.failures.join("; "))
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} |",
            r.number,
            r.name,
            r.expected,
            r.report.measured.replace('|', "\\|"),
            outcome.replace('|', "\\|")
        );
    }
    out
}
