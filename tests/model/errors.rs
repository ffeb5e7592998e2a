//! Every way a `.pinc` file can be wrong gives a typed error; none panics.

use crate::common;
use pinc::model::{FORMAT_VERSION, HEADER_SIZE, MAGIC, MAX_FILE_BYTES, ModelError, PincModel};

fn good_bytes() -> Vec<u8> {
    common::with_extras(common::paper_4x32(9)).to_bytes().unwrap()
}

/// Re-frames `payload` with a valid header and checksum, so only the payload is at fault.
pub(crate) fn framed(payload: &[u8], version: u32) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    out.extend_from_slice(&version.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

#[test]
fn rejects_truncation_at_every_offset() {
    let bytes = good_bytes();
    for len in 0..bytes.len() {
        let err = PincModel::from_bytes(&bytes[..len]).unwrap_err();
        assert!(matches!(err, ModelError::Truncated { .. }), "cut at {len}: {err}");
    }
}

#[test]
fn rejects_random_bit_flips() {
    let bytes = good_bytes();
    let mut rng = common::Rng(42);
    for _ in 0..5000 {
        let mut b = bytes.clone();
        let bit = (rng.next_u64() % (b.len() as u64 * 8)) as usize;
        b[bit / 8] ^= 1 << (bit % 8);
        let err = PincModel::from_bytes(&b).unwrap_err();
        assert!(
            matches!(
                err,
                ModelError::BadMagic { .. }
                    | ModelError::UnsupportedVersion { .. }
                    | ModelError::TooLarge { .. }
                    | ModelError::Truncated { .. }
                    | ModelError::TrailingBytes { .. }
                    | ModelError::ChecksumMismatch { .. }
            ),
            "bit {bit}: {err}"
        );
    }
}

#[test]
fn rejects_wrong_magic() {
    let mut b = good_bytes();
    b[0] = b'X';
    assert!(matches!(PincModel::from_bytes(&b), Err(ModelError::BadMagic { .. })));
    assert!(matches!(PincModel::from_bytes(b"GIF89a"), Err(ModelError::BadMagic { .. })));
}

#[test]
fn rejects_future_version() {
    let mut b = good_bytes();
    b[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    let err = PincModel::from_bytes(&b).unwrap_err();
    assert!(
        matches!(err, ModelError::UnsupportedVersion { found, supported } if found == FORMAT_VERSION + 1 && supported == FORMAT_VERSION)
    );
    assert!(
        err.to_string().contains("format version 5") && err.to_string().contains("versions 1 to 4; a newer pinc"),
        "{err}"
    );
}

#[test]
fn rejects_huge_declared_length_before_allocating() {
    let mut b = good_bytes();
    b[12..20].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(
        matches!(PincModel::from_bytes(&b), Err(ModelError::TooLarge { declared: u64::MAX, max }) if max < MAX_FILE_BYTES)
    );
}

#[test]
fn rejects_huge_length_prefix_inside_the_payload() {
    // The first field of the payload is `state_inputs: Vec<u8>`, whose varint length prefix
    // is its first byte (9). Replace it with a 2^62 length (0xFD + u64) and re-checksum.
    let good = good_bytes();
    let payload = &good[HEADER_SIZE..];
    assert_eq!(payload[0], 9);
    let mut evil = vec![0xFD];
    evil.extend_from_slice(&(1u64 << 62).to_le_bytes());
    evil.extend_from_slice(&payload[1..]);
    let err = PincModel::from_bytes(&framed(&evil, FORMAT_VERSION)).unwrap_err();
    assert!(matches!(err, ModelError::Decode(_)), "{err}");
}

#[test]
fn rejects_nan_weights() {
    let mut m = common::paper_4x32(1);
    m.weights.hidden[2].linear.weight[17] = f32::NAN;
    let err = PincModel::from_bytes(&m.to_bytes_unvalidated().unwrap()).unwrap_err();
    assert!(matches!(&err, ModelError::NonFinite { what, index: 17, .. } if what == "hidden[2].weight"), "{err}");
    // Saving refuses it too.
    assert!(matches!(m.to_bytes(), Err(ModelError::NonFinite { .. })));
    let mut m = common::with_extras(common::paper_4x32(1));
    m.envelope.as_mut().unwrap().input_max[1] = f64::INFINITY;
    assert!(matches!(PincModel::from_bytes(&m.to_bytes_unvalidated().unwrap()), Err(ModelError::NonFinite { .. })));
}

#[test]
fn rejects_inconsistent_dimensions() {
    let bad = |f: &dyn Fn(&mut PincModel)| {
        let mut m = common::with_extras(common::paper_4x32(1));
        f(&mut m);
        PincModel::from_bytes(&m.to_bytes_unvalidated().unwrap()).unwrap_err()
    };
    let e = bad(&|m| m.weights.hidden[1].linear.weight.pop().map(|_| ()).unwrap());
    assert!(
        matches!(&e, ModelError::DimensionMismatch { what, expected: 1024, found: 1023 } if what == "hidden[1].weight length"),
        "{e}"
    );
    let e = bad(&|m| m.architecture.width = 33);
    assert!(matches!(e, ModelError::DimensionMismatch { .. }), "{e}");
    let e = bad(&|m| m.architecture.hidden_layers = 5);
    assert!(matches!(e, ModelError::DimensionMismatch { .. }), "{e}");
    let e = bad(&|m| m.weights.output.rows = 8);
    assert!(matches!(e, ModelError::DimensionMismatch { .. }), "{e}");
    let e = bad(&|m| m.architecture.layer_norm[1] = true);
    assert!(matches!(e, ModelError::Invalid { .. } | ModelError::DimensionMismatch { .. }), "{e}");
    let e = bad(&|m| m.architecture.state_inputs = vec![0, 2, 1, 3, 4, 5, 6, 7, 8]);
    assert!(matches!(e, ModelError::Invalid { .. }), "{e}");
    let e = bad(&|m| m.input_scaling.as_mut().unwrap().std[3] = 0.0);
    assert!(matches!(e, ModelError::Invalid { .. }), "{e}");
    let e = bad(&|m| m.weights.hidden[0].beta = 0.0);
    assert!(matches!(e, ModelError::Invalid { .. }), "{e}");
    let e = bad(&|m| m.dt = -0.08);
    assert!(matches!(e, ModelError::Invalid { .. }), "{e}");
    let e = bad(&|m| m.architecture.width = 1 << 20);
    assert!(matches!(e, ModelError::LimitExceeded { .. }), "{e}");
}

#[test]
fn rejects_trailing_bytes() {
    let mut b = good_bytes();
    b.push(0);
    assert!(matches!(PincModel::from_bytes(&b), Err(ModelError::TrailingBytes { extra: 1 })));
}

#[test]
fn missing_file_is_an_io_error_naming_it() {
    let err = PincModel::load("/nonexistent/model.pinc").unwrap_err();
    assert!(matches!(err, ModelError::Io { .. }));
    assert!(err.to_string().contains("/nonexistent/model.pinc"));
}
