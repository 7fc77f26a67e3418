//! Single calls of the hot paths: the Eq. 11 tick, re-conditioning one group, a CACLA-MTL
//! update, and one evaluation of each forward model (the RBF network pre-training runs against,
//! the polynomial kinematics whose Jacobian steers the corrections).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use nalgebra::DMatrix;
use serde_json::{Map, Value};
use softarm_config::activation::ActivationConfig;
use softarm_config::arm::ArmConfig;
use softarm_config::demonstrations::DemoRecipe;
use softarm_config::forward_model::NetworkConfig;
use softarm_config::kinematics::PolynomialConfig;
use softarm_config::learner::LearnerConfig;
use softarm_config::learner::PretrainConfig;
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::pcc;
use softarm_kinematics::poly::Polynomial;
use softarm_kinematics::rbf::RbfNetwork;
use softarm_method::blend::{Planner, Timeline};
use softarm_method::promp::{Basis, Demonstration, Primitive, TrainConfig};
use softarm_model::pipeline::{self, Training, TrainingData};

use super::{Out, Stats, header, histogram, record, row};

/// The default `[arm]`'s actuators: the arm the calls are timed on.
const N: usize = 6;

/// Times each call; the `calls` object of the JSON output.
pub(super) fn run(
    ticks: usize,
    reconditions: usize,
    out: &Out,
    stop: &AtomicBool,
) -> anyhow::Result<Value> {
    out.progress("timing single calls");
    let mut t = Timed {
        out,
        stop,
        results: Map::new(),
        sink: 0.0,
    };
    let config = ArmConfig::default();
    let arm = pcc::Arm::of_config(&config).map_err(anyhow::Error::msg)?;
    let demos = TrainingData::<N>::from_plant(&config, &DemoRecipe::default(), 1)?;
    t.blend(&demos, ticks, reconditions)?;
    t.blend_wider::<9>(&demos, ticks, reconditions)?;
    t.blend_wider::<16>(&demos, ticks, reconditions)?;
    t.cacla_update(&arm, &demos, ticks.min(100_000))?;
    t.forward_models(&arm, &demos, ticks.min(100_000))?;
    std::hint::black_box(t.sink);
    Ok(Value::Object(t.results))
}

/// The sections' rows and JSON, and a sink the timed results go into so none is optimised away.
struct Timed<'a> {
    out: &'a Out,
    stop: &'a AtomicBool,
    results: Map<String, Value>,
    sink: f64,
}

impl Timed<'_> {
    /// The row and the JSON entry of one call's histogram; an error once interrupted.
    fn report(
        &mut self,
        key: &str,
        name: &str,
        ns: &hdrhistogram::Histogram<u64>,
    ) -> anyhow::Result<()> {
        let s = Stats::of(ns).expect("at least one call timed");
        self.out.text(&row(name, &s, ""));
        self.results.insert(key.to_string(), s.json());
        if self.stop.load(Ordering::Relaxed) {
            anyhow::bail!("interrupted");
        }
        Ok(())
    }

    /// The Eq. 11 tick, and re-conditioning one group then ticking where it is needed.
    fn blend(
        &mut self,
        demos: &TrainingData<N>,
        ticks: usize,
        reconditions: usize,
    ) -> anyhow::Result<()> {
        let (actuation, _task) = pipeline::primitives(&demos.recordings, 15)?;
        self.out.text(&header(&format!(
            "Single calls (N=5 conditioning points, M=3 primitives, D={N}, K=15, 10 s at 500 Hz)"
        )));
        self.time_blend::<N>(actuation, ticks, reconditions, "")
    }

    /// [`Timed::blend`] on an arm of `A` actuators: primitives of the default `[arm]`'s
    /// demonstrations widened to `A` (actuator d follows a mix of two of its `N`), their timing
    /// the point.
    fn blend_wider<const A: usize>(
        &mut self,
        demos: &TrainingData<N>,
        ticks: usize,
        reconditions: usize,
    ) -> anyhow::Result<()> {
        let basis = Basis::new(15, None)?;
        let classes = demos
            .recordings
            .iter()
            .map(|r| r.class + 1)
            .max()
            .unwrap_or(0);
        let primitives = (0..classes)
            .map(|class| {
                let mine: Vec<Demonstration> = demos
                    .recordings
                    .iter()
                    .filter(|r| r.class == class)
                    .map(|r| {
                        let wide = DMatrix::from_fn(r.times.len(), A, |i, d| {
                            let a = &r.actuation[i];
                            0.5 * (a[d % N] + a[(5 * d + 1) % N])
                        });
                        Demonstration::new(r.times.clone(), wide)
                    })
                    .collect();
                Primitive::train(basis.clone(), &mine, &TrainConfig::default())
            })
            .collect::<Result<Vec<_>, _>>()?;
        self.out
            .text(&format!("  the same on an arm of {A} actuators (D={A}):"));
        self.time_blend::<A>(primitives, ticks, reconditions, &format!("_d{A}"))
    }

    /// Times the tick and re-condition + ready on `primitives`; JSON keys end in `suffix`.
    fn time_blend<const A: usize>(
        &mut self,
        primitives: Vec<Primitive>,
        ticks: usize,
        reconditions: usize,
        suffix: &str,
    ) -> anyhow::Result<()> {
        let t_cond = [1.0, 3.0, 5.0, 7.0, 9.0];
        let planner = Planner::<A>::new(
            primitives,
            &t_cond,
            &[0, 1, 2, 1, 0],
            Timeline::new(10.0, 500.0)?,
            ActivationConfig::default(),
            1e-6,
        )?;
        let (mut blend, mut replanner) = planner.start(&[[0.5; A]; 5])?;
        let engine_ticks = blend.timeline().ticks();
        let mut ns = histogram();
        for i in 0..ticks {
            let start = Instant::now();
            let v = blend.tick(std::hint::black_box(i % engine_ticks));
            record(&mut ns, start);
            self.sink += v[0];
        }
        self.report(&format!("eq11_tick{suffix}"), "Eq. 11 tick", &ns)?;

        let k3 = blend.timeline().tick_of(t_cond[3]);
        let mut ns = histogram();
        for i in 0..reconditions {
            let a = [0.4 + 0.002 * i as f64; A];
            let start = Instant::now();
            replanner.recondition(1, &a, 2)?;
            self.sink += blend.tick(k3)[0];
            record(&mut ns, start);
        }
        self.report(
            &format!("recondition{suffix}"),
            "re-condition one group + ready",
            &ns,
        )
    }

    /// A CACLA-MTL update at a conditioning point, five points visited in turn as in an
    /// execution, on a learner warmed up by one imitation pass and a short pre-training on the
    /// kinematic model.
    fn cacla_update(
        &mut self,
        arm: &pcc::Arm,
        demos: &TrainingData<N>,
        updates: usize,
    ) -> anyhow::Result<()> {
        let warm = Training {
            basis_functions: 15,
            forward: NetworkConfig::default(),
            kinematics: Default::default(),
            learner: LearnerConfig::default(),
            pretrain: PretrainConfig {
                max_epochs: 2_000,
                ..Default::default()
            },
            imitation_passes: 1,
        };
        let positions = &demos.positions;
        let (mut learner, _) =
            pipeline::learner(&warm, arm, &demos.actuations, positions, |_| true)?;
        let mut ns = histogram();
        let mut memory = [None; 5];
        for i in 0..updates {
            let point = i % 5;
            let target = positions[(i / 100 * 5 + point) * 37 % positions.len()];
            let memory = &mut memory[point];
            let a = learner.act(memory.as_ref(), &target, true);
            let reached = arm.position(&a);
            let start = Instant::now();
            let visit = learner.observe(memory, &target, &a, &reached);
            record(&mut ns, start);
            self.sink += visit.error;
        }
        self.report(
            "cacla_update",
            "CACLA-MTL update at a conditioning point",
            &ns,
        )
    }

    /// The PCC kinematics the sim's plant runs, and the forward models as `softarm train` fits
    /// them (the shipped [forward_model] and [kinematics] settings) on D_fwd of the
    /// demonstrations, evaluated at the demonstrated actuations in turn.
    fn forward_models(
        &mut self,
        arm: &pcc::Arm,
        demos: &TrainingData<N>,
        evaluations: usize,
    ) -> anyhow::Result<()> {
        let (inputs, positions) = (&demos.actuations, &demos.positions);
        let net = RbfNetwork::fit(inputs, positions, &NetworkConfig::default())?;
        let poly = Polynomial::fit(inputs, positions, &PolynomialConfig::default())
            .map_err(anyhow::Error::msg)?;
        let models: [(&str, String, &dyn ForwardModel<N>); 3] = [
            (
                "pcc_forward",
                "PCC kinematics of the sim, one call".into(),
                arm,
            ),
            (
                "rbf_forward",
                format!("RBF forward model, one call ({} centres)", net.centres()),
                &net,
            ),
            (
                "poly_forward",
                format!(
                    "polynomial kinematics, one call ({} terms)",
                    poly.weights().len()
                ),
                &poly,
            ),
        ];
        for (key, name, model) in models {
            let mut ns = histogram();
            for i in 0..evaluations {
                let a = std::hint::black_box(&inputs[i * 7 % inputs.len()]);
                let start = Instant::now();
                let p = model.position(a);
                record(&mut ns, start);
                self.sink += p[0];
            }
            self.report(key, &name, &ns)?;
        }
        Ok(())
    }
}
