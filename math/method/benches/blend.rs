//! Criterion benches of Eq. 11 (the Blend): one Eq. 11 tick and re-condition + ready on arms of
//! 6 (the paper's), 9 (a three-segment TDCR) and 16 actuators (the most an arm may have),
//! training, one conditioning. `cargo bench -p softarm-method --bench blend`. Percentiles of
//! single ticks: `softarm-rig bench`.

#[path = "../tests/common/mod.rs"]
mod common;

use std::hint::black_box;

use common::{D, demonstrations, primitives, primitives_of};
use criterion::{Criterion, criterion_group, criterion_main};
use softarm_method::blend::{Planner, Timeline};
use softarm_method::promp::{Basis, Primitive, TrainConfig, ViaPoint};
use softarm_sections::activation::ActivationConfig;

const T_COND: [f64; 5] = [1.0, 3.0, 5.0, 7.0, 9.0];
const Q: [usize; 5] = [0, 1, 2, 1, 0];

fn planner<const A: usize>() -> Planner<A> {
    Planner::new(
        primitives_of(3, 15, A),
        &T_COND,
        &Q,
        Timeline::new(10.0, 500.0).unwrap(),
        ActivationConfig::default(),
        1e-6,
    )
    .unwrap()
}

/// The tick and re-condition + ready on an arm of `A` actuators.
fn blend<const A: usize>(c: &mut Criterion) {
    let (mut blend, mut replanner) = planner::<A>().start(&[[0.5; A]; 5]).unwrap();
    let ticks = blend.timeline().ticks();
    let mut k = 0;
    c.bench_function(&format!("tick (N=5 M=3 D={A} K=15)"), |b| {
        b.iter(|| {
            k = (k + 1) % ticks;
            black_box(blend.tick(black_box(k)))
        })
    });

    // UpdatePrim for group 1 and the tick that takes it in (at T_cond[3], group 1 is inactive).
    let k3 = blend.timeline().tick_of(T_COND[3]);
    let mut x = 0.0;
    c.bench_function(
        &format!("recondition + ready (D={A}, 10 s at 500 Hz)"),
        |b| {
            b.iter(|| {
                x = (x + 0.01) % 0.3;
                replanner.recondition(1, &[0.4 + x; A], 2).unwrap();
                black_box(blend.tick(k3));
            })
        },
    );
}

fn benches(c: &mut Criterion) {
    blend::<D>(c);
    blend::<9>(c);
    blend::<16>(c);

    let demos: Vec<_> = (0..3).map(|class| demonstrations(class, 20)).collect();
    c.bench_function("train M=3 primitives from 20 demos each", |b| {
        b.iter(|| {
            for d in &demos {
                black_box(
                    Primitive::train(Basis::new(15, None).unwrap(), d, &TrainConfig::default())
                        .unwrap(),
                );
            }
        })
    });

    let p = primitives(1, 15).remove(0);
    let via = ViaPoint::exact(0.4, &[0.5; D]);
    c.bench_function("condition one primitive (D=6 K=15)", |b| {
        b.iter(|| {
            let mut q = p.clone();
            q.condition(black_box(&via)).unwrap();
            black_box(q)
        })
    });
}

criterion_group!(blend_benches, benches);
criterion_main!(blend_benches);
