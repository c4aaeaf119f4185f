//! Case 14: stuck chains (digest §5.14). Rejection run lengths of chains on a floor that is half rough
//! metal, half mirror: HSLT alone cannot move a path camera → mirror → light (a Dirac vertex), and the
//! chain must not force-accept it ([C13] does after 30000 rejections, which biases); mixed with the
//! bidirectional mutation every such chain can leave it.

use super::{bdpt_for, seeding};
use crate::integrators::Bdpt;
use crate::metropolis::mutations::bidir::BidirectionalMutation;
use crate::metropolis::mutations::halfvector::{HalfVectorMutation, HalfVectorParams};
use crate::metropolis::{
    Chain, MutationStats, PathContext, PathSeeds, PathState, TargetFunction, WeightedMutation,
};
use crate::sampling::Sampler;
use crate::scene::Scene;
use crate::stability::scenes::from_xml;
use crate::stability::{CaseReport, Effort};

/// The mirror reflects 5%: at full reflectance the light's mirror image is so much brighter than the
/// rough highlight that the target itself keeps chains there (80 of 96 mixed chains stayed for 200
/// steps), which would hide the question asked here.
const SCENE: &str = r#"<scene version="3.0.0">
  <integrator type="bdpt"><integer name="max_depth" value="2" /></integrator>
  <sensor type="perspective">
    <float name="fov" value="50" />
    <transform name="to_world"><lookat origin="0, -4, 3" target="0, 0, 0" up="0, 0, 1" /></transform>
    <film type="hdrfilm"><integer name="width" value="32" /><integer name="height" value="24" /></film>
  </sensor>
  <shape type="rectangle">
    <transform name="to_world"><scale x="2" y="4" /><translate x="-2" /></transform>
    <bsdf type="conductor"><rgb name="specular_reflectance" value="0.05, 0.05, 0.05" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale x="2" y="4" /><translate x="2" /></transform>
    <bsdf type="roughconductor"><string name="distribution" value="beckmann" /><float name="alpha" value="0.2" /></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.5" /><rotate x="1" angle="180" /><translate x="-0.5" y="2" z="2.5" /></transform>
    <emitter type="area"><rgb name="radiance" value="20, 20, 20" /></emitter>
  </shape>
</scene>"#;

/// Rejection runs of a set of chains: lengths of the completed and final runs, and how many chains
/// never moved at all.
struct Runs {
    lengths: Vec<usize>,
    never_moved: usize,
    chains: usize,
    stats: MutationStats,
    /// Per chain that never moved: the sum of its acceptance probabilities, the expected number of
    /// moves it had; above 0 the state can be left, it only takes a while.
    stuck_acceptance: Vec<f64>,
    /// Per mutation of the mixture, in its order.
    per_mutation: Vec<MutationStats>,
}

impl Runs {
    fn describe(&self) -> String {
        let mut sorted = self.lengths.clone();
        sorted.sort_unstable();
        let pick = |q: f64| sorted.get(((sorted.len() as f64 - 1.0) * q) as usize).copied().unwrap_or(0);
        let mean = sorted.iter().sum::<usize>() as f64 / sorted.len().max(1) as f64;
        format!(
            "{} chains, runs mean {mean:.1} median {} p99 {} max {}, never moved {}",
            self.chains,
            pick(0.5),
            pick(0.99),
            pick(1.0),
            self.never_moved
        )
    }
}

fn chains(
    scene: &Scene,
    bdpt: &Bdpt,
    seeds: &PathSeeds,
    on_mirror: bool,
    with_bidir: bool,
    count: usize,
    steps: usize,
) -> Runs {
    let mut rng = Sampler::new(14, on_mirror as u64, with_bidir as u64);
    let mut runs = Runs {
        lengths: Vec::new(),
        never_moved: 0,
        chains: 0,
        stats: MutationStats::default(),
        per_mutation: Vec::new(),
        stuck_acceptance: Vec::new(),
    };
    let mut attempts = 0;
    while runs.chains < count && attempts < 200 * count {
        attempts += 1;
        let Some(start) = seeds.draw(scene, bdpt, 14, rng.next_f64()) else { continue };
        if start.vertices.len() != 3 || start.vertices[1].delta != on_mirror {
            continue;
        }
        let mut mutations: Vec<WeightedMutation<PathState, PathContext>> = vec![WeightedMutation {
            mutation: Box::new(HalfVectorMutation::new(HalfVectorParams::default())),
            weight: 1.0,
        }];
        if with_bidir {
            mutations.push(WeightedMutation { mutation: Box::new(BidirectionalMutation), weight: 1.0 });
        }
        let mut chain =
            Chain::new(start, mutations, TargetFunction::Luminance, Sampler::new(14, runs.chains as u64, 3));
        let mut ctx = PathContext::new(scene, bdpt);
        let accepted = |c: &Chain<PathState, PathContext>| c.stats().iter().map(|s| s.accepted).sum::<u64>();
        let (mut run, mut moved) = (0usize, false);
        for _ in 0..steps {
            let before = accepted(&chain);
            chain.step(&mut ctx, &mut |_: &PathState, _| {});
            if accepted(&chain) > before {
                runs.lengths.push(run);
                run = 0;
                moved = true;
            } else {
                run += 1;
            }
        }
        runs.lengths.push(run);
        runs.never_moved += !moved as usize;
        if !moved {
            runs.stuck_acceptance.push(chain.stats().iter().map(|m| m.acceptance_sum).sum());
        }
        runs.chains += 1;
        runs.per_mutation.resize(chain.stats().len(), MutationStats::default());
        for (i, s) in chain.stats().iter().enumerate() {
            runs.stats.add(s);
            runs.per_mutation[i].name = s.name;
            runs.per_mutation[i].add(s);
        }
    }
    runs
}

pub fn run(effort: Effort) -> CaseReport {
    let mut report = CaseReport::new();
    let scene = from_xml("stuck-floor", SCENE);
    let bdpt = bdpt_for(&scene);
    let seeds = seeding(&scene, &bdpt, 14, 20_000);
    let (count, steps) = (effort.scale(96, 512), effort.scale(1000, 3000));

    let rough = chains(&scene, &bdpt, &seeds, false, false, count, steps);
    report.measure(format!("HSLT only, rough start: {}", rough.describe()));
    report.check(rough.chains == count, "too few rough-floor seeds");
    report.check(
        rough.never_moved * 2 < rough.chains,
        "HSLT hardly moves on the rough floor: nothing to compare",
    );

    let mirror = chains(&scene, &bdpt, &seeds, true, false, count, steps);
    report.measure(format!("HSLT only, mirror start: {}", mirror.describe()));
    report.check(mirror.chains == count, "too few camera-mirror-light seeds");
    // Not applicable on every step and no acceptance at all: nothing forces the chain off the path.
    report.check(
        mirror.never_moved == mirror.chains && mirror.stats.not_applicable == mirror.stats.proposed,
        format!(
            "a chain HSLT cannot move moved anyway ({} of {})",
            mirror.chains - mirror.never_moved,
            mirror.chains
        ),
    );

    let mixed = chains(&scene, &bdpt, &seeds, true, true, count, steps);
    let bidir = &mixed.per_mutation[1];
    report.measure(format!(
        "HSLT + bidirectional, mirror start: {} (bidirectional: {} proposed, {} accepted, {} rejected, {} zero, failed [{}])",
        mixed.describe(),
        bidir.proposed,
        bidir.accepted,
        bidir.rejected,
        bidir.rejected_zero,
        super::failures(bidir)
    ));
    // The bright mirror image is a state the target wants the chain to linger in, so some chains
    // stay for all the steps; what must hold is that each had a positive probability of leaving:
    // Σ a > 0 over its proposals (bidirectional proposals that regrow the emitter can reach it back).
    let least = mixed.stuck_acceptance.iter().copied().filter(|&a| a > 0.0).fold(f64::INFINITY, f64::min);
    let zero = mixed.stuck_acceptance.iter().filter(|&&a| a == 0.0).count();
    report.measure(if mixed.stuck_acceptance.is_empty() {
        "every mixed chain left the mirror path".to_string()
    } else {
        format!(
            "of the {} mixed chains that stayed put, {zero} had Σ acceptance 0, the others ≥ {least:.1e} (expected moves)",
            mixed.stuck_acceptance.len()
        )
    });
    report.check(mixed.chains == count, "too few camera-mirror-light seeds");
    report
        .check(mixed.never_moved < mixed.chains, "the bidirectional mutation moved no chain off the mirror");
    report.check(
        mixed.stuck_acceptance.iter().all(|&a| a > 0.0),
        "a chain on a mirror path had zero probability of leaving it despite the bidirectional mutation",
    );
    report
}
