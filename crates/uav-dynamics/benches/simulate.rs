//! Criterion bench of the flight simulator (`sim::simulate`): IMU steps per second on a
//! random training route with default sensors (200 Hz IMU, 10 Hz GPS/attitude/VO), and one
//! closed-loop step. Figures go into docs/performance.md.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use uav_dynamics::controller::{ClosedLoopSim, ControllerConfig};
use uav_dynamics::sim::{SimConfig, simulate};
use uav_dynamics::trajectory::{RandomRoute, RandomRouteConfig, ShapeConfig, square};

fn bench_simulate(c: &mut Criterion) {
    let cfg = SimConfig::default();
    let Ok(route) = RandomRoute::new(&RandomRouteConfig::default(), 1) else { return };
    let duration_s = 60.0;
    let mut g = c.benchmark_group("simulate");
    g.throughput(Throughput::Elements(12_001));
    g.bench_function("random_route_60s", |b| {
        b.iter(|| simulate(black_box(&cfg), &route, duration_s, 7).map(|f| f.truth.len()).unwrap_or(0));
    });
    g.finish();

    let Ok(sq) = square(&ShapeConfig::default()) else { return };
    let mut g = c.benchmark_group("closed_loop");
    g.throughput(Throughput::Elements(1000));
    g.bench_function("step_x1000", |b| {
        b.iter(|| {
            let Ok(mut sim) = ClosedLoopSim::new(&cfg, ControllerConfig::default(), &sq, 3) else { return 0.0 };
            let mut est = sim.initial_estimate();
            for _ in 0..1000 {
                if let Ok(s) = sim.step(&est) {
                    est.p = s.sensors.truth.p;
                    est.v = s.sensors.truth.v;
                }
            }
            est.p.x
        });
    });
    g.finish();
}

criterion_group!(benches, bench_simulate);
criterion_main!(benches);
