//! ROS 2 bags written by `rosbags` (tests/fixtures/ros2/make_bags.py) in both storage formats:
//! every stream against the values the writer wrote, converted to NED / FRD by hand here.

use pinc::Input;
use pinc::dataset::import::{CommandsToInput, ImportError, Ros2Options, StreamSet, read_ros2};
use serde_json::Value;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ros2").join(name)
}

fn values() -> Value {
    serde_json::from_str(&std::fs::read_to_string(fixture("values.json")).unwrap()).unwrap()
}

fn messages<'a>(v: &'a Value, bag: &str, topic: &str) -> &'a Vec<Value> {
    v[bag][topic]["messages"].as_array().unwrap()
}

fn f3(m: &Value, key: &str) -> [f64; 3] {
    let a = m[key].as_array().unwrap();
    [a[0].as_f64().unwrap(), a[1].as_f64().unwrap(), a[2].as_f64().unwrap()]
}

fn ns(m: &Value, key: &str) -> i64 {
    m[key].as_i64().unwrap()
}

/// Seconds from `t0` (ns).
fn secs(t: i64, t0: i64) -> f64 {
    (t - t0) as f64 * 1e-9
}

fn close(a: f64, b: f64, what: &str) {
    assert!((a - b).abs() < 1e-9, "{what}: {a} != {b}");
}

fn no_converter() -> Option<CommandsToInput<'static>> {
    None
}

fn default_read(path: &str) -> StreamSet {
    read_ros2(&fixture(path), &Ros2Options::default(), no_converter()).unwrap()
}

/// ENU yaw, roll, pitch of a quaternion `(x, y, z, w)` (Z-Y-X), written out.
fn euler(q: [f64; 4]) -> [f64; 3] {
    let [x, y, z, w] = q;
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    [roll, pitch, yaw]
}

fn wrap(a: f64) -> f64 {
    (a.sin()).atan2(a.cos())
}

#[test]
fn odometry_and_wrench_in_enu_flu_read_as_ned_frd_with_the_signs_of_a_right_turn() {
    let v = values();
    for (bag, path) in [("enu_mcap", "enu_mcap"), ("enu_sqlite3", "enu_sqlite3/enu_sqlite3.db3")] {
        let s = default_read(path);
        let t0 = v["t0_ns"].as_i64().unwrap();
        let odom = messages(&v, bag, "/odom");
        let pos = s.position.as_ref().unwrap();
        let att = s.attitude.as_ref().unwrap();
        let vb = s.velocity_body.as_ref().unwrap();
        let r = s.yaw_rate.as_ref().unwrap();
        assert_eq!(pos.len(), odom.len());
        assert_eq!(pos.source, "/odom");
        for (k, m) in odom.iter().enumerate() {
            let t = secs(ns(m, "stamp_ns"), t0);
            for series_t in [pos.t[k], att.t[k], vb.t[k], r.t[k]] {
                close(series_t, t, "time is header.stamp");
            }
            let [e, n, u] = f3(m, "position");
            assert_eq!(pos.v[k], [n, e, -u], "ENU (x, y, z) -> NED (y, x, -z)");
            let q = m["orientation_xyzw"].as_array().unwrap();
            let q = [0, 1, 2, 3].map(|i| q[i].as_f64().unwrap());
            let [roll, pitch, yaw] = euler(q);
            close(att.v[k][0], roll, "roll");
            close(att.v[k][1], -pitch, "pitch: FLU nose-down positive, FRD nose-up positive");
            close(att.v[k][2], wrap(FRAC_PI_2 - yaw), "psi = pi/2 - ENU yaw");
            let [lu, lv, lw] = f3(m, "linear");
            assert_eq!(vb.v[k], [lu, -lv, -lw]);
            assert_eq!(r.v[k][0], -f3(m, "angular")[2]);
        }
        // The known motion: heading north-east, turning right, forward, descending.
        close(att.v[0][2], FRAC_PI_4 + 0.1 * pos.t[0], "heads north-east: psi = +pi/4 at t = 0");
        assert!(att.v.last().unwrap()[2] > att.v[0][2], "a right turn increases psi");
        assert!(r.v.iter().all(|x| (x[0] - 0.1).abs() < 1e-12), "turning right: r = +0.1 in pinc");
        assert!(pos.v.last().unwrap()[2] > pos.v[0][2], "descending: z grows");
        assert!(vb.v.iter().all(|x| (x[2] - 0.2).abs() < 1e-12 && x[0] == 0.5 && x[1] == -0.05));
        assert!(pos.v.last().unwrap()[0] > pos.v[0][0] && pos.v.last().unwrap()[1] > pos.v[0][1], "moves north-east");

        let wrench = messages(&v, bag, "/wrench");
        let input = s.input.as_ref().unwrap();
        assert_eq!(input.len(), wrench.len());
        for (k, m) in wrench.iter().enumerate() {
            let stamp = ns(m, "stamp_ns");
            let t = if stamp == 0 { ns(m, "recv_ns") } else { stamp };
            close(input.t[k], secs(t, t0), "wrench time (zero stamp: receive time)");
            let f = f3(m, "force");
            let n = f3(m, "torque");
            assert_eq!(input.v[k], [f[0], -f[1], -f[2], -n[2]], "FLU force and moment -> FRD");
        }
        assert!(s.velocity_ned.is_none() && s.depth.is_none());
        assert!(s.notes.iter().any(|n| n.contains("\"odom\" read as ENU") && n.contains("\"base_link\" as FLU")));
        assert!(s.notes.iter().any(|n| n.contains("/wrench: 1 messages with a zero header.stamp")));
    }
}

#[test]
fn both_storage_formats_give_identical_streams() {
    for name in ["enu", "ned"] {
        let a = default_read(&format!("{name}_mcap"));
        let b = default_read(&format!("{name}_sqlite3"));
        assert_eq!(a, b, "{name}");
    }
}

#[test]
fn the_same_motion_logged_in_ned_frd_reads_to_the_same_streams() {
    let enu = default_read("enu_mcap");
    let ned = default_read("ned_sqlite3");
    let pairs3 =
        [(&enu.position, &ned.position), (&enu.attitude, &ned.attitude), (&enu.velocity_body, &ned.velocity_body)];
    for (a, b) in pairs3 {
        let (a, b) = (a.as_ref().unwrap(), b.as_ref().unwrap());
        assert_eq!(a.t, b.t);
        for (x, y) in a.v.iter().zip(&b.v) {
            for i in 0..3 {
                close(x[i], y[i], &a.source);
            }
        }
    }
    assert_eq!(enu.yaw_rate, ned.yaw_rate);
    assert_eq!(enu.input, ned.input);
    assert!(ned.notes.iter().any(|n| n.contains("\"odom_ned\" read as NED") && n.contains("\"base_link_frd\" as FRD")));
}

#[test]
fn named_pose_and_twist_topics_replace_the_odometry() {
    let v = values();
    let opts =
        Ros2Options { pose_topic: Some("/pose".into()), twist_topic: Some("/twist".into()), ..Default::default() };
    for bag in ["enu_mcap", "ned_mcap"] {
        let s = read_ros2(&fixture(bag), &opts, no_converter()).unwrap();
        let poses = messages(&v, bag, "/pose");
        let twists = messages(&v, bag, "/twist");
        // t = 0 at the first message read: the first pose (odometry is not read).
        let t0 = ns(&poses[0], "recv_ns");
        let pos = s.position.as_ref().unwrap();
        let att = s.attitude.as_ref().unwrap();
        assert_eq!(pos.source, "/pose");
        assert_eq!(pos.len(), poses.len());
        for (k, m) in poses.iter().enumerate() {
            close(pos.t[k], secs(ns(m, "stamp_ns"), t0), "pose time");
            let p = f3(m, "position");
            let q = m["orientation_xyzw"].as_array().unwrap();
            let [roll, pitch, yaw] = euler([0, 1, 2, 3].map(|i| q[i].as_f64().unwrap()));
            if bag == "enu_mcap" {
                assert_eq!(pos.v[k], [p[1], p[0], -p[2]]);
                close(att.v[k][2], wrap(FRAC_PI_2 - yaw), "psi");
                close(att.v[k][1], -pitch, "pitch");
            } else {
                assert_eq!(pos.v[k], p);
                close(att.v[k][2], yaw, "psi");
                close(att.v[k][1], pitch, "pitch");
            }
            close(att.v[k][0], roll, "roll");
        }
        let r = s.yaw_rate.as_ref().unwrap();
        assert_eq!(r.len(), twists.len());
        for (k, m) in twists.iter().enumerate() {
            close(r.t[k], secs(ns(m, "stamp_ns"), t0), "twist time");
            let l = f3(m, "linear");
            let a = f3(m, "angular");
            if bag == "enu_mcap" {
                // Body frame base_link: FLU.
                assert_eq!(s.velocity_body.as_ref().unwrap().v[k], [l[0], -l[1], -l[2]]);
                assert_eq!(r.v[k][0], -a[2]);
                assert!(s.velocity_ned.is_none());
            } else {
                // World frame odom_ned: already NED.
                assert_eq!(s.velocity_ned.as_ref().unwrap().v[k], l);
                assert_eq!(r.v[k][0], a[2]);
                assert!(s.velocity_body.is_none());
            }
        }
    }
}

#[test]
fn thruster_outputs_go_through_the_given_converter() {
    let v = values();
    // A stand-in for the vehicle's thrusters: recognisable combinations of the channels.
    let conv = |c: &[f64]| Input::from([c[0] - 1500.0, c[1] - c[0], c[7], c.len() as f64]);
    let conv_ref: &dyn Fn(&[f64]) -> Input = &conv;

    let opts = Ros2Options { outputs_topic: Some("/mavros/rc/out".into()), ..Default::default() };
    let s = read_ros2(&fixture("enu_sqlite3"), &opts, Some(conv_ref)).unwrap();
    let t0 = v["t0_ns"].as_i64().unwrap();
    let input = s.input.unwrap();
    let rc = messages(&v, "enu_sqlite3", "/mavros/rc/out");
    assert_eq!(input.len(), rc.len());
    for (k, m) in rc.iter().enumerate() {
        let c: Vec<f64> = m["channels"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        close(input.t[k], secs(ns(m, "stamp_ns"), t0), "RCOut time is header.stamp");
        assert_eq!(input.v[k], [c[0] - 1500.0, c[1] - c[0], c[7], 8.0]);
    }

    let opts = Ros2Options { outputs_topic: Some("/fmu/out/actuator_outputs".into()), ..Default::default() };
    let s = read_ros2(&fixture("ned_mcap"), &opts, Some(conv_ref)).unwrap();
    let input = s.input.unwrap();
    let px4 = messages(&v, "ned_mcap", "/fmu/out/actuator_outputs");
    assert_eq!(input.len(), px4.len());
    for (k, m) in px4.iter().enumerate() {
        let o: Vec<f64> = m["output"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        close(input.t[k], secs(ns(m, "recv_ns"), t0), "ActuatorOutputs time is the receive time");
        assert_eq!(input.v[k], [o[0] - 1500.0, o[1] - o[0], o[7], 8.0], "noutputs = 8 channels passed");
    }
    assert!(s.notes.iter().any(|n| n.contains("autopilot's boot")));

    let err = read_ros2(&fixture("ned_mcap"), &opts, no_converter()).unwrap_err();
    assert!(err.to_string().contains("thrusters"), "{err}");
}

#[test]
fn a_missing_or_mistyped_topic_is_an_error_listing_every_topic_and_type() {
    let opts = Ros2Options { odometry_topic: Some("/nope".into()), ..Default::default() };
    for bag in ["enu_mcap", "enu_sqlite3"] {
        let err = read_ros2(&fixture(bag), &opts, no_converter()).unwrap_err();
        assert!(matches!(err, ImportError::Malformed { .. }));
        let msg = err.to_string();
        for listed in [
            "no topic /nope",
            "/odom [nav_msgs/msg/Odometry]",
            "/pose [geometry_msgs/msg/PoseStamped]",
            "/twist [geometry_msgs/msg/TwistStamped]",
            "/wrench [geometry_msgs/msg/WrenchStamped]",
            "/mavros/rc/out [mavros_msgs/msg/RCOut]",
        ] {
            assert!(msg.contains(listed), "{listed} not in: {msg}");
        }
    }
    let opts = Ros2Options { odometry_topic: Some("/wrench".into()), ..Default::default() };
    let msg = read_ros2(&fixture("enu_mcap"), &opts, no_converter()).unwrap_err().to_string();
    assert!(msg.contains("/wrench is geometry_msgs/msg/WrenchStamped"), "{msg}");
}

#[test]
fn a_quaternion_off_unit_length_is_an_error_naming_topic_and_time() {
    let v = values();
    let stamp = ns(&messages(&v, "bad_quat_mcap", "/odom")[1], "stamp_ns");
    let err = read_ros2(&fixture("bad_quat_mcap"), &Ros2Options::default(), no_converter()).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("/odom") && msg.contains(&format!("{stamp} ns")) && msg.contains("quaternion"), "{msg}");
    assert!(msg.contains("1.01"), "{msg}");
}

#[test]
fn frame_options_override_the_names() {
    // Declared NED / FRD, the ENU bag's values pass unconverted.
    let v = values();
    let opts = Ros2Options {
        world_frame: Some("ned".parse().unwrap()),
        body_frame: Some("frd".parse().unwrap()),
        ..Default::default()
    };
    let s = read_ros2(&fixture("enu_mcap"), &opts, no_converter()).unwrap();
    let odom = messages(&v, "enu_mcap", "/odom");
    for (k, m) in odom.iter().enumerate() {
        assert_eq!(s.position.as_ref().unwrap().v[k], f3(m, "position"));
        assert_eq!(s.velocity_body.as_ref().unwrap().v[k], f3(m, "linear"));
        assert_eq!(s.yaw_rate.as_ref().unwrap().v[k][0], f3(m, "angular")[2]);
    }
    assert!(s.notes.iter().any(|n| n.contains("\"odom\" read as NED") && n.contains("\"base_link\" as FRD")));
}

#[test]
fn a_file_that_is_no_bag_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    std::fs::write(&path, b"not a bag at all").unwrap();
    let msg = read_ros2(&path, &Ros2Options::default(), no_converter()).unwrap_err().to_string();
    assert!(msg.contains("run.mcap") && msg.contains("neither an MCAP file nor an SQLite"), "{msg}");
    let empty = tempfile::tempdir().unwrap();
    let msg = read_ros2(empty.path(), &Ros2Options::default(), no_converter()).unwrap_err().to_string();
    assert!(msg.contains("without a .mcap or .db3 file"), "{msg}");
}
