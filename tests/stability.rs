//! The fifteen stiff and extreme cases of the HSLT method digest (§5), one test each: every case's
//! checks (in `hslt::stability`) must pass at the test suite's sample counts. `hslt stability` prints
//! the same cases, at the table's sample counts, into docs/stability.md.

use hslt::stability::{cases, Effort};

fn check(number: usize) {
    let case = cases().into_iter().find(|c| c.number == number).expect("no such case");
    let report = (case.run)(Effort::Quick);
    eprintln!("case {number} ({}): {}", case.name, report.measured);
    assert!(report.passed(), "case {number} ({}) failed: {}", case.name, report.failures.join("; "));
}

#[test]
fn every_case_is_registered_once() {
    let numbers: Vec<usize> = cases().iter().map(|c| c.number).collect();
    assert_eq!(numbers, (1..=15).collect::<Vec<_>>());
}

#[test]
fn case_01_near_specular() {
    check(1);
}

#[test]
fn case_02_very_rough() {
    check(2);
}

#[test]
fn case_03_grazing() {
    check(3);
}

#[test]
fn case_04_long_chains() {
    check(4);
}

#[test]
fn case_05_near_singular_lens() {
    check(5);
}

#[test]
fn case_06_tir_slab() {
    check(6);
}

#[test]
fn case_07_frame_rotation() {
    check(7);
}

#[test]
fn case_08_flat_shading() {
    check(8);
}

#[test]
fn case_09_degenerate_endpoints() {
    check(9);
}

#[test]
fn case_10_index_matched_interfaces() {
    check(10);
}

#[test]
fn case_11_mobius_kernel() {
    check(11);
}

#[test]
fn case_12_detailed_balance() {
    check(12);
}

#[test]
fn case_13_scale_invariance() {
    check(13);
}

#[test]
fn case_14_stuck_chains() {
    check(14);
}

#[test]
fn case_15_f32_against_f64() {
    check(15);
}
