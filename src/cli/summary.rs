//! What `hslt render` prints when it ends: samples, time and throughput, and for the Metropolis
//! integrators the acceptance, cost and failures of each mutation and the chains that got stuck.

use crate::image::Metadata;
use crate::render::RenderStats;
use std::path::PathBuf;

pub(super) fn print_summary(outputs: &[PathBuf], stats: &RenderStats, threads: usize) {
    let secs = stats.elapsed.as_secs_f64().max(1e-9);
    eprintln!(
        "{} spp in {:.2} s on {} threads: {:.3} M samples/s, {:.2} M rays/s{}{}",
        stats.min_spp,
        secs,
        threads,
        stats.samples as f64 / secs * 1e-6,
        stats.rays as f64 / secs * 1e-6,
        if stats.invalid_samples > 0 {
            format!(", {} NaN/Inf samples dropped", stats.invalid_samples)
        } else {
            String::new()
        },
        if stats.interrupted { " (interrupted)" } else { "" },
    );
    for o in outputs {
        eprintln!("wrote {}", o.display());
    }
}

/// Metropolis statistics (acceptance per mutation) and warnings such as an all-black seeding pass.
pub(super) fn print_metropolis_summary(meta: &Metadata) {
    let get = |key: &str| meta.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str());
    if let Some(status) = get("hslt.mlt.status") {
        eprintln!("warning: {status}");
    }
    if let (Some(m), Some(a)) = (get("hslt.mlt.mutations"), get("hslt.mlt.acceptance")) {
        eprintln!("{m} mutations, acceptance {a}");
        if let (Some(stuck), Some(chains), Some(longest), Some(share)) = (
            get("hslt.mlt.chains_stuck"),
            get("hslt.mlt.chains"),
            get("hslt.mlt.longest_rejection_streak"),
            get("hslt.mlt.stuck_share"),
        ) {
            eprintln!(
                "chains stuck ({} or more rejections in a row): {stuck} of {chains}; longest run {longest}; \
                 share of mutations in such runs {share}",
                crate::metropolis::chain::STUCK_STREAK
            );
        }
        if let Some(note) =
            seed_concentration_note(get("hslt.mlt.seed_largest_share"), get("hslt.mlt.chains"))
        {
            eprintln!("note: {note}");
        }
        for (k, v) in meta {
            let Some(name) = k.strip_prefix("hslt.mlt.").and_then(|r| r.strip_suffix(".acceptance")) else {
                continue;
            };
            let field = |what: &str| get(&format!("hslt.mlt.{name}.{what}")).unwrap_or("0").to_string();
            let cost = get(&format!("hslt.mlt.{name}.microseconds_per_proposal"))
                .map(|us| format!(", {us} µs each"))
                .unwrap_or_default();
            let mut line = format!(
                "  {name}: {} proposed, acceptance {v}{cost}, {} zero-contribution, {} not applicable",
                field("proposed"),
                field("rejected_zero"),
                field("not_applicable")
            );
            let prefix = format!("hslt.mlt.{name}.");
            let detail = |part: &str| -> Vec<String> {
                meta.iter()
                    .filter_map(|(key, value)| {
                        let rest = key.strip_prefix(&prefix)?.strip_prefix(part)?;
                        Some(format!("{rest} {value}"))
                    })
                    .collect()
            };
            let failed = detail("failed.");
            if !failed.is_empty() {
                line += &format!("; failed: {}", failed.join(", "));
            }
            let means = detail("mean.");
            if !means.is_empty() {
                line += &format!("; mean {}", means.join(", "));
            }
            eprintln!("{line}");
        }
    }
}

/// Share of b on one seed path at which the summary says so: chains start on it in proportion, and
/// where they cannot leave (near-specular paths) the image keeps that much energy near it. On jewelry
/// (64×48, 20 s) the renders whose heaviest seed path held 1.6–1.8% had the largest error; on
/// nested-glass the old 2^16-sample pass put 4.3% on one path (docs/rough-glass.md).
const CONCENTRATED_SHARE: f64 = 0.01;

/// A note when one seed path holds a large share of b (and so about share × chains of the chains).
fn seed_concentration_note(share: Option<&str>, chains: Option<&str>) -> Option<String> {
    let share: f64 = share?.parse().ok()?;
    let chains: f64 = chains?.parse().ok()?;
    let on_one = share * chains;
    (share >= CONCENTRATED_SHARE && on_one >= 1.0).then(|| {
        format!(
            "one seed path carries {:.1}% of the light, so about {on_one:.0} of {chains:.0} chains start on it; \
             where the mutations cannot move them (near-specular paths) the image keeps that energy there \
             (a longer seeding pass, --seed-share or --seed-paths, spreads it thinner)",
            100.0 * share
        )
    })
}

#[cfg(test)]
mod tests {
    use super::seed_concentration_note;

    #[test]
    fn the_note_appears_only_when_one_seed_path_holds_much_of_b() {
        assert_eq!(seed_concentration_note(Some("1.8e-3"), Some("4096")), None);
        assert_eq!(seed_concentration_note(Some("2.0e-2"), Some("16")), None, "no chain expected on it");
        let note = seed_concentration_note(Some("4.3e-2"), Some("1024")).expect("44 chains on one path");
        assert!(note.contains("4.3%") && note.contains("about 44 of 1024"), "{note}");
        assert_eq!(seed_concentration_note(None, Some("1024")), None);
        assert_eq!(seed_concentration_note(Some("nan?"), Some("1024")), None);
    }
}
