//! Import speed of the CSV readers on generated 100 000-row files (the target is at least one
//! million rows per second on one core):
//!
//! - `import_csv/read_csv_100k`: today's header `t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz`, no mapping.
//! - `import_csv/read_mapped_csv_100k`: a BlueROV2 Heavy style export (27 columns, no time
//!   column, ENU position, x-y-z-w quaternion, FLU velocities, yaw rate and wrench, eight
//!   PWMs) through a mapping that reads 15 of its columns and converts every frame.
//!
//! Criterion prints the rate in elements per second: one element is one row. Numbers are
//! written as a logger prints them (shortest round-trip decimal form of a computed value).
//!
//! Run with `cargo bench --features tools --bench import_csv`.
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pinc::dataset::import::{CsvMapping, read_csv, read_mapped_csv};
use std::fmt::Write as _;
use std::hint::black_box;

const ROWS: usize = 100_000;

fn todays_format() -> String {
    let mut s = String::from("t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz\n");
    for k in 0..ROWS {
        let t = k as f64 * 0.08;
        let a = 0.01 * k as f64;
        writeln!(
            s,
            "{t},{},{},{},{},{},{},{},{},{},{},{},{}",
            3.0 * a.cos(),
            3.0 * a.sin(),
            1.0 + 0.1 * a,
            a.sin(),
            0.3 + 0.01 * a.cos(),
            0.05 * a.sin(),
            0.1,
            0.2 * a.cos(),
            10.0 * a.sin(),
            3.0 * a.cos(),
            5.0,
            0.8 * a.sin()
        )
        .unwrap();
    }
    s
}

fn bluerov_heavy_format() -> String {
    let mut s = String::from(
        "pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,ang_vel_x,ang_vel_y,ang_vel_z,\
         pwm_1,pwm_2,pwm_3,pwm_4,pwm_5,pwm_6,pwm_7,pwm_8,force_x,force_y,force_z,torque_x,torque_y,torque_z\n",
    );
    for k in 0..ROWS {
        let a = 0.01 * k as f64;
        let (qz, qw) = ((a / 2.0).sin(), (a / 2.0).cos());
        write!(
            s,
            "{},{},{},0,0,{qz},{qw},{},{},{},0,0,{}",
            3.0 * a.sin(),
            3.0 * a.cos(),
            -0.1 * a,
            0.3,
            0.01 * a.sin(),
            -0.1,
            -0.2
        )
        .unwrap();
        for c in 0..8 {
            write!(s, ",{}", 1500 + (k * (c + 3)) % 400).unwrap();
        }
        writeln!(s, ",{},{},{},0,0,{}", 10.0 * a.sin(), -3.0 * a.cos(), -5.0, -0.8 * a.cos()).unwrap();
    }
    s
}

const MAPPING: &str = r#"
[time]
rate_hz = 10.0
[position]
columns = ["pos_x", "pos_y", "pos_z"]
frame = "enu"
[heading]
quaternion_columns = ["quat_x", "quat_y", "quat_z", "quat_w"]
order = "xyzw"
frame = "enu_flu"
[velocity]
columns = ["vel_x", "vel_y", "vel_z"]
axes = "body_flu"
[yaw_rate]
column = "ang_vel_z"
axes = "flu"
[input]
wrench_columns = ["force_x", "force_y", "force_z", "torque_z"]
axes = "flu"
"#;

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let today = dir.path().join("today.csv");
    std::fs::write(&today, todays_format()).unwrap();
    let heavy = dir.path().join("heavy.csv");
    std::fs::write(&heavy, bluerov_heavy_format()).unwrap();
    let mapping: CsvMapping = toml::from_str(MAPPING).unwrap();

    let mut g = c.benchmark_group("import_csv");
    g.throughput(Throughput::Elements(ROWS as u64));
    g.sample_size(20);
    g.bench_function("read_csv_100k", |b| b.iter(|| black_box(read_csv(black_box(&today)).unwrap())));
    g.bench_function("read_mapped_csv_100k", |b| {
        b.iter(|| black_box(read_mapped_csv(black_box(&heavy), &mapping, None).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
