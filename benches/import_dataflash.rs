//! Import speed of ArduPilot dataflash logs: `read_bin` on the two .BIN fixtures
//! (`tests/fixtures/ardusub/`: the real ArduSub `small.BIN`, 294 kB, and the first 1.4 MB of
//! the simulator's `sitl_excite_1.BIN`, most of it 400 Hz `SIM2` records the reader steps
//! over), from reading the file (in the page cache) to the stream set with thruster inputs.
//! Criterion reports bytes per second (the issue asks for at least 100 MB/s).
//!
//! Run with `cargo bench --features tools --bench import_dataflash`.
#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pinc::Input;
use pinc::dataset::import::{ArdupilotOptions, InputSource, read_bin};
use std::hint::black_box;
use std::path::PathBuf;

fn bench(c: &mut Criterion) {
    let opts = ArdupilotOptions {
        inputs: InputSource::ThrusterOutputs,
        thrusters: Some(Box::new(|p: &[f64]| Input::from([p[0], p[1], p[2], p[3]]))),
        ..ArdupilotOptions::default()
    };
    let mut group = c.benchmark_group("import_dataflash");
    for name in ["small.BIN", "sitl_excite_1_head.BIN"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ardusub").join(name);
        let len = std::fs::metadata(&path).unwrap().len();
        group.throughput(Throughput::Bytes(len));
        group.bench_function(name, |b| b.iter(|| black_box(read_bin(black_box(&path), &opts).unwrap())));
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
