//! CSV logs of any layout through a mapping file: every field read back against the values
//! the writer wrote, frames and signs against a known motion, and bad input as one line
//! naming the file, the column and the row.

use pinc::Input;
use pinc::dataset::import::{CsvMapping, ImportError, StreamSet, load_mapping, read_csv, read_mapped_csv};
use std::f64::consts::{FRAC_PI_2, PI};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn mapping(dir: &Path, text: &str) -> CsvMapping {
    load_mapping(&write(dir, "mapping.toml", text)).unwrap()
}

fn close(a: f64, b: f64, what: &str) {
    assert!((a - b).abs() < 1e-9, "{what}: {a} != {b}");
}

/// The motion written to the BlueROV2-style file, in pinc's frames: heading 30 deg east of
/// north at t = 0, turning right (clockwise seen from above) at 0.2 rad/s, 0.3 m/s forward,
/// descending at 0.1 m/s, starting at north 2 m, east -1 m, depth 1.5 m.
const PSI0: f64 = PI / 6.0;
const R: f64 = 0.2;
const U: f64 = 0.3;
const W: f64 = 0.1;

fn psi(t: f64) -> f64 {
    PSI0 + R * t
}

/// NED position from integrating `x' = u cos psi, y' = u sin psi, z' = w` in closed form.
fn ned(t: f64) -> [f64; 3] {
    [2.0 + U / R * (psi(t).sin() - PSI0.sin()), -1.0 - U / R * (psi(t).cos() - PSI0.cos()), 1.5 + W * t]
}

/// The wrench in pinc's body axes (forward-right-down): forward, to the right, down, and a
/// moment turning right.
const WRENCH_FRD: [f64; 4] = [10.0, 3.0, 5.0, 0.8];

/// A file in the style of a real-tank BlueROV2 Heavy export: no time column, 10 Hz, z-up
/// (ENU) position, quaternion in x, y, z, w order (FLU body to ENU world), FLU velocities and
/// angular rates, eight thruster PWMs and the wrench in FLU.
fn bluerov_heavy_csv(rows: usize) -> String {
    let mut s = String::from(
        "pos_x,pos_y,pos_z,quat_x,quat_y,quat_z,quat_w,vel_x,vel_y,vel_z,ang_vel_x,ang_vel_y,ang_vel_z,\
         pwm_1,pwm_2,pwm_3,pwm_4,pwm_5,pwm_6,pwm_7,pwm_8,force_x,force_y,force_z,torque_x,torque_y,torque_z\n",
    );
    for k in 0..rows {
        let t = k as f64 / 10.0;
        let [n, e, d] = ned(t);
        // ENU: x east, y north, z up; yaw counter-clockwise from east.
        let yaw_enu = FRAC_PI_2 - psi(t);
        let (qz, qw) = ((yaw_enu / 2.0).sin(), (yaw_enu / 2.0).cos());
        // FLU: the forward speed as is, the descent along -up, the right turn about +up is negative.
        let [fx, fy, fz, mz] = WRENCH_FRD;
        let pwm: Vec<String> = (1..=8).map(|c| (1500 + 10 * c + k % 7).to_string()).collect();
        writeln!(
            s,
            "{e},{n},{},0,0,{qz},{qw},{U},0,{},0,0,{},{},{fx},{},{},0,0,{}",
            -d,
            -W,
            -R,
            pwm.join(","),
            -fy,
            -fz,
            -mz
        )
        .unwrap();
    }
    s
}

const BLUEROV_MAPPING: &str = r#"
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

#[test]
fn a_bluerov_heavy_export_in_enu_and_flu_reads_as_the_ned_frd_motion_that_was_written() {
    let dir = tempfile::tempdir().unwrap();
    let rows = 50;
    let csv = write(dir.path(), "tank.csv", &bluerov_heavy_csv(rows));
    let s: StreamSet = read_mapped_csv(&csv, &mapping(dir.path(), BLUEROV_MAPPING), None).unwrap();

    let pos = s.position.as_ref().unwrap();
    let att = s.attitude.as_ref().unwrap();
    let vel = s.velocity_body.as_ref().unwrap();
    let rate = s.yaw_rate.as_ref().unwrap();
    let input = s.input.as_ref().unwrap();
    assert!(s.velocity_ned.is_none() && s.depth.is_none());
    for series_t in [&pos.t, &att.t, &vel.t, &rate.t, &input.t] {
        assert_eq!(series_t.len(), rows);
        for (k, t) in series_t.iter().enumerate() {
            close(*t, k as f64 * 0.1, "t");
        }
    }
    close(att.v[0][2], 30f64.to_radians(), "psi at t = 0");
    for k in 0..rows {
        let t = k as f64 / 10.0;
        let [x, y, z] = ned(t);
        close(pos.v[k][0], x, "x (north)");
        close(pos.v[k][1], y, "y (east)");
        close(pos.v[k][2], z, "z (down)");
        close(att.v[k][0], 0.0, "roll");
        close(att.v[k][1], 0.0, "pitch");
        close(att.v[k][2], psi(t), "psi");
        // Turning right: -0.2 about FLU's up axis is +0.2 about pinc's down axis.
        close(rate.v[k][0], 0.2, "r");
        close(vel.v[k][0], 0.3, "u");
        close(vel.v[k][1], 0.0, "v");
        close(vel.v[k][2], 0.1, "w (down)");
        for (i, what) in ["X", "Y", "Z", "Mz"].iter().enumerate() {
            close(input.v[k][i], WRENCH_FRD[i], what);
        }
        if k > 0 {
            assert!(pos.v[k][2] > pos.v[k - 1][2], "descending: z grows");
            assert!(att.v[k][2] > att.v[k - 1][2], "turning right: psi grows");
        }
    }
    assert_eq!(input.source, "force_x,force_y,force_z,torque_z");
    let notes = s.notes.join("\n");
    assert!(notes.contains("fixed rate of 10 Hz"), "{notes}");
    assert!(notes.contains("position: pos_x,pos_y,pos_z in ENU"), "{notes}");
    assert!(notes.contains("FLU body to ENU world"), "{notes}");
    assert!(notes.contains("body FLU axes"), "{notes}");
    assert!(notes.contains("sign flipped"), "{notes}");
    assert!(notes.contains("50 rows"), "{notes}");
}

#[test]
fn thruster_columns_reach_the_thrusters_by_channel() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write(dir.path(), "tank.csv", &bluerov_heavy_csv(5));
    // The columns listed out of order with their channels: pwm_3 is channel 3, and so on.
    let text = r#"
[time]
rate_hz = 10.0
[input]
thruster_columns = ["pwm_8", "pwm_1", "pwm_3"]
channels = [8, 1, 3]
"#;
    let m = mapping(dir.path(), text);
    let thrusters =
        |cmd: &[f64]| Input::from([cmd[0], cmd[2], cmd[7], cmd.len() as f64 + if cmd[1].is_nan() { 0.5 } else { 0.0 }]);
    let s = read_mapped_csv(&csv, &m, Some(&thrusters)).unwrap();
    let input = s.input.unwrap();
    assert_eq!(input.len(), 5);
    for k in 0..5 {
        let pwm = |c: usize| (1500 + 10 * c + k % 7) as f64;
        // Channel 2 is not mapped: NaN, 8 channels in all.
        assert_eq!(input.v[k], [pwm(1), pwm(3), pwm(8), 8.5]);
    }
    assert!(s.position.is_none() && s.attitude.is_none());
    // Without the vehicle's thrusters the commands cannot become a wrench.
    let err = read_mapped_csv(&csv, &m, None).unwrap_err().to_string();
    assert!(err.contains("tank.csv") && err.contains("thruster"), "{err}");
}

#[test]
fn a_mapping_naming_a_missing_column_is_refused_naming_it_and_listing_the_header() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write(dir.path(), "tank.csv", &bluerov_heavy_csv(3));
    let m = mapping(dir.path(), &BLUEROV_MAPPING.replace("\"quat_w\"", "\"quat_real\""));
    let err = read_mapped_csv(&csv, &m, None).unwrap_err();
    assert!(matches!(err, ImportError::Malformed { .. }));
    let err = err.to_string();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("tank.csv"), "{err}");
    assert!(err.contains("\"quat_real\"") && err.contains("[heading] quaternion_columns"), "{err}");
    assert!(err.contains("the file has: pos_x, pos_y, pos_z, quat_x"), "{err}");
    assert!(err.contains("torque_z"), "{err}");
}

#[test]
fn a_quaternion_that_is_not_unit_length_is_refused_naming_the_row_and_the_columns() {
    let dir = tempfile::tempdir().unwrap();
    let mut lines: Vec<String> = bluerov_heavy_csv(6).lines().map(str::to_string).collect();
    // Data row 4 (line 5): the quaternion scaled by 0.9.
    let mut fields: Vec<String> = lines[4].split(',').map(str::to_string).collect();
    for f in &mut fields[3..7] {
        *f = (f.parse::<f64>().unwrap() * 0.9).to_string();
    }
    lines[4] = fields.join(",");
    let csv = write(dir.path(), "bad_quat.csv", &(lines.join("\n") + "\n"));
    let err = read_mapped_csv(&csv, &mapping(dir.path(), BLUEROV_MAPPING), None).unwrap_err().to_string();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("bad_quat.csv"), "{err}");
    assert!(err.contains("line 5") && err.contains("data row 4"), "{err}");
    assert!(err.contains("quat_x,quat_y,quat_z,quat_w"), "{err}");
    assert!(err.contains("length 0.9"), "{err}");
}

#[test]
fn a_yaw_in_degrees_and_time_in_milliseconds_are_converted() {
    let dir = tempfile::tempdir().unwrap();
    // Semicolons, a yaw clockwise from north in degrees, ENU world velocities, a missing field.
    let csv = write(
        dir.path(),
        "ms.csv",
        "stamp_ms; hdg_deg; ve; vn; vu; r_dps\n1000;30;1;2;3;-10\n1250;-170;0.5;0;-1;20\n1500;;0;0;0;0\n",
    );
    let text = r#"
delimiter = ";"
[time]
column = "stamp_ms"
unit = "ms"
[heading]
yaw_column = "hdg_deg"
unit = "deg"
frame = "ned"
[velocity]
columns = ["ve", "vn", "vu"]
axes = "world_enu"
[yaw_rate]
column = "r_dps"
axes = "frd"
unit = "deg"
"#;
    let s = read_mapped_csv(&csv, &mapping(dir.path(), text), None).unwrap();
    let att = s.attitude.unwrap();
    assert_eq!(att.t, vec![1.0, 1.25, 1.5]);
    close(att.v[0][2], 30f64.to_radians(), "psi row 1");
    close(att.v[1][2], (-170f64).to_radians(), "psi row 2");
    assert!(att.v[2][2].is_nan(), "an empty field is a missing value");
    let vel = s.velocity_ned.unwrap();
    assert!(s.velocity_body.is_none());
    assert_eq!(vel.v[0], [2.0, 1.0, -3.0]);
    assert_eq!(vel.v[1], [0.0, 0.5, 1.0]);
    let rate = s.yaw_rate.unwrap();
    close(rate.v[0][0], (-10f64).to_radians(), "r row 1");
    close(rate.v[1][0], 20f64.to_radians(), "r row 2");

    // The same heading counter-clockwise from east: 60 deg ENU is 30 deg east of north.
    let enu = text.replace("frame = \"ned\"", "frame = \"enu\"");
    let csv = write(dir.path(), "enu.csv", "stamp_ms;hdg_deg;ve;vn;vu;r_dps\n0;60;0;0;0;0\n100;-90;0;0;0;0\n");
    let att = read_mapped_csv(&csv, &mapping(dir.path(), &enu), None).unwrap().attitude.unwrap();
    close(att.v[0][2], 30f64.to_radians(), "ENU 60 deg");
    close(att.v[1][2], PI, "ENU -90 deg (south)");
}

#[test]
fn a_mapping_with_an_unknown_key_or_two_choices_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        dir.path(),
        "m.toml",
        "[time]\nrate_hz = 10.0\n\n[position]\ncolumns = [\"a\", \"b\", \"c\"]\nframe = \"ned\"\nfame = 1\n",
    );
    let err = load_mapping(&path).unwrap_err().to_string();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("m.toml") && err.contains("line 7") && err.contains("fame"), "{err}");

    let path = write(dir.path(), "two.toml", "[time]\nrate_hz = 10.0\ncolumn = \"t\"\n");
    let err = load_mapping(&path).unwrap_err().to_string();
    assert!(err.contains("two.toml") && err.contains("[time]") && err.contains("not both"), "{err}");

    let path =
        write(dir.path(), "frame.toml", "[time]\nrate_hz = 10.0\n[heading]\nyaw_column = \"y\"\nframe = \"enu_flu\"\n");
    let err = load_mapping(&path).unwrap_err().to_string();
    assert!(err.contains("[heading] frame"), "{err}");
}

#[test]
fn todays_header_without_a_mapping_reads_every_field_exactly_as_written() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<[f64; 13]> = (0..20)
        .map(|k| {
            let k = k as f64;
            std::array::from_fn(|j| {
                if j == 0 { k * 0.08 } else { (1.0 + j as f64) * (0.37 * k + 0.1 * j as f64).sin() / 3.0 }
            })
        })
        .collect();
    let mut text = String::from("t, x, y, z, psi, u, v, w, r, X, Y, Z, Mz\n");
    for (k, r) in rows.iter().enumerate() {
        let fields: Vec<String> = r
            .iter()
            .enumerate()
            .map(|(j, v)| if k == 7 && j == 5 { String::new() } else { format!("{v:e}") })
            .collect();
        writeln!(text, "{}", fields.join(" , ")).unwrap();
    }
    let rec = read_csv(&write(dir.path(), "today.csv", &text)).unwrap();
    assert_eq!(rec.t.len(), 20);
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(rec.t[k].to_bits(), r[0].to_bits());
        for j in 0..8 {
            if k == 7 && j == 4 {
                assert!(rec.states[k][j].is_nan());
            } else {
                assert_eq!(rec.states[k][j].to_bits(), r[1 + j].to_bits(), "row {k} state {j}");
            }
        }
        for j in 0..4 {
            assert_eq!(rec.inputs[k][j].to_bits(), r[9 + j].to_bits(), "row {k} input {j}");
        }
    }
}

/// A log whose logger lost power mid-write ends in a torn line (the published tank dataset
/// has one: `line 3997: 16 fields, the header has 72`): every complete row is read, the torn
/// one skipped and said so in the report; the same damage before the last line is an error.
#[test]
fn a_torn_last_line_is_skipped_and_noted_and_a_damaged_middle_row_refused() {
    let dir = tempfile::tempdir().unwrap();
    let text = bluerov_heavy_csv(20);
    let torn_at = text.trim_end().rfind(',').unwrap() - 60; // inside the last row
    let csv = write(dir.path(), "torn.csv", &text[..torn_at]);
    let s = read_mapped_csv(&csv, &mapping(dir.path(), BLUEROV_MAPPING), None).unwrap();
    assert_eq!(s.position.as_ref().unwrap().t.len(), 19);
    let note = s.notes.iter().find(|n| n.contains("last line")).unwrap_or_else(|| panic!("{:?}", s.notes));
    assert!(note.starts_with("line 21: ") && note.contains("fields, the header has 27"), "{note}");
    // The same row cut short in the middle of the file.
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[10] = lines[10].split(',').take(16).collect::<Vec<_>>().join(",");
    let middle = write(dir.path(), "middle.csv", &(lines.join("\n") + "\n"));
    let err = read_mapped_csv(&middle, &mapping(dir.path(), BLUEROV_MAPPING), None).unwrap_err().to_string();
    assert!(err.contains("middle.csv") && err.contains("line 11: 16 fields, the header has 27"), "{err}");
}
