//! Import speed of a ROS 2 MCAP bag of Odometry (50 Hz) and WrenchStamped (10 Hz), the CDR
//! messages `rosbags` wrote in tests/fixtures/ros2, copied with advancing stamps into a bag of
//! about 64 MB; reported as MB/s of bag read (`read_ros2` end to end).

#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use pinc::dataset::import::{Ros2Options, read_ros2};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One message of each topic of the fixture bag: (topic, schema name, schema text, payload).
fn templates() -> Vec<(String, String, Vec<u8>, Vec<u8>)> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ros2/enu_mcap/enu_mcap.mcap");
    let bytes = std::fs::read(path).unwrap();
    let mut out: Vec<(String, String, Vec<u8>, Vec<u8>)> = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if (m.channel.topic == "/odom" || m.channel.topic == "/wrench") && !out.iter().any(|o| o.0 == m.channel.topic) {
            let s = m.channel.schema.as_ref().unwrap();
            out.push((m.channel.topic.clone(), s.name.clone(), s.data.to_vec(), m.data.to_vec()));
        }
    }
    out
}

/// Writes `seconds` of Odometry at 50 Hz and WrenchStamped at 10 Hz; returns the bytes of
/// messages written.
fn write_bag(path: &Path, seconds: u64, compression: Option<mcap::Compression>) -> u64 {
    let t = templates();
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new().compression(compression).create(file).unwrap();
    let mut channels = Vec::new();
    for (topic, name, schema, _) in &t {
        let sid = w.add_schema(name, "ros2msg", schema).unwrap();
        channels.push(w.add_channel(sid, topic, "cdr", &BTreeMap::new()).unwrap());
    }
    let mut seq = 0;
    let mut total = 0u64;
    for k in 0..seconds * 50 {
        let ns = 1_700_000_000_000_000_000u64 + k * 20_000_000;
        for (i, (_, _, _, payload)) in t.iter().enumerate() {
            if i == 1 && k % 5 != 0 {
                continue;
            }
            // header.stamp sits right after the 4-byte encapsulation header.
            let mut data = payload.clone();
            data[4..8].copy_from_slice(&((ns / 1_000_000_000) as i32).to_le_bytes());
            data[8..12].copy_from_slice(&((ns % 1_000_000_000) as u32).to_le_bytes());
            let header =
                mcap::records::MessageHeader { channel_id: channels[i], sequence: seq, log_time: ns, publish_time: ns };
            seq += 1;
            total += data.len() as u64;
            w.write_to_known_channel(&header, &data).unwrap();
        }
    }
    w.finish().unwrap();
    total
}

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let mut group = c.benchmark_group("import_ros2");
    group.sample_size(10);
    for (name, compression) in [("mcap_uncompressed", None), ("mcap_zstd", Some(mcap::Compression::Zstd))] {
        let path = dir.path().join(format!("{name}.mcap"));
        // 90 000 odometry messages: about 64 MB of messages.
        let decoded = write_bag(&path, 1800, compression);
        let size = std::fs::metadata(&path).unwrap().len();
        // Throughput in bytes of messages decoded, so both variants count the same work.
        group.throughput(Throughput::Bytes(decoded));
        eprintln!("{name}: file {:.1} MB, messages {:.1} MB", size as f64 / 1e6, decoded as f64 / 1e6);
        group.bench_function(name, |b| {
            b.iter(|| read_ros2(&path, &Ros2Options::default(), None).unwrap());
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
