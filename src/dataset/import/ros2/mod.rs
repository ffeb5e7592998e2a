//! Recorded runs from ROS 2 bags (MCAP or sqlite3 storage, CDR messages): odometry, poses,
//! twists and wrenches, or thruster outputs, converted to pinc's frames (`frames`).
//!
//! Time base: `header.stamp`, or the bag's receive time where a stamp is zero and for PX4's
//! `ActuatorOutputs` (its `timestamp` counts from the autopilot's boot, another clock); `t = 0`
//! is the earliest receive time of the messages read. Both go into `StreamSet::notes`.

mod frames;
mod messages;
mod storage;

pub use frames::{BodyFrame, WorldFrame};

use super::{ImportError, Series, StreamSet};
use frames::{attitude, body_of, is_world, partner, rotate, to_frd, to_ned, world_of};
use messages::decode;
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::path::Path;
use storage::{Bag, Topic};

/// Which topics to read and how to read their frames. A topic left `None` is chosen by its
/// message type when exactly one topic of the bag has it.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ros2Options {
    /// `nav_msgs/msg/Odometry`: position and attitude, body velocity and yaw rate.
    pub odometry_topic: Option<String>,
    /// `geometry_msgs/msg/PoseStamped`: position and attitude (named here, it replaces the
    /// odometry's; by default it is read only without odometry).
    pub pose_topic: Option<String>,
    /// `geometry_msgs/msg/TwistStamped`: velocity and yaw rate (same precedence as the pose).
    pub twist_topic: Option<String>,
    /// `geometry_msgs/msg/WrenchStamped`: the input, in a body frame.
    pub wrench_topic: Option<String>,
    /// `mavros_msgs/msg/RCOut` or `px4_msgs/msg/ActuatorOutputs`: thruster commands, turned
    /// into the input by the vehicle's thrusters (named here, it replaces the wrench).
    pub outputs_topic: Option<String>,
    /// The convention of every world frame, instead of the one its name implies.
    pub world_frame: Option<WorldFrame>,
    /// The convention of every body frame, instead of the one its name implies.
    pub body_frame: Option<BodyFrame>,
}

pub use super::streams::CommandsToInput;

/// What a topic is read for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Odometry,
    Pose,
    Twist,
    Wrench,
    Outputs,
}

const ODOMETRY: &str = "nav_msgs/msg/Odometry";
const POSE: &str = "geometry_msgs/msg/PoseStamped";
const TWIST: &str = "geometry_msgs/msg/TwistStamped";
const WRENCH: &str = "geometry_msgs/msg/WrenchStamped";
const RCOUT: &str = "mavros_msgs/msg/RCOut";
const ACTUATOR_OUTPUTS: &str = "px4_msgs/msg/ActuatorOutputs";

impl Role {
    fn types(self) -> &'static [&'static str] {
        match self {
            Role::Odometry => &[ODOMETRY],
            Role::Pose => &[POSE],
            Role::Twist => &[TWIST],
            Role::Wrench => &[WRENCH],
            Role::Outputs => &[RCOUT, ACTUATOR_OUTPUTS],
        }
    }

    fn option(self) -> &'static str {
        match self {
            Role::Odometry => "--odometry-topic",
            Role::Pose => "--pose-topic",
            Role::Twist => "--twist-topic",
            Role::Wrench => "--wrench-topic",
            Role::Outputs => "--outputs-topic",
        }
    }
}

/// `pkg/msg/Name` for `pkg/Name` too (both spellings occur in bags).
fn canonical(msg_type: &str) -> String {
    match msg_type.split('/').collect::<Vec<_>>()[..] {
        [pkg, name] => format!("{pkg}/msg/{name}"),
        _ => msg_type.to_string(),
    }
}

/// Every topic with its type, for error messages.
fn listing(topics: &[Topic]) -> String {
    let all: Vec<String> = topics.iter().map(|t| format!("{} [{}]", t.name, t.msg_type)).collect();
    if all.is_empty() { "no topics".into() } else { all.join(", ") }
}

/// The topic read for `role`: the one named, or the only one of its type.
fn select(bag: &Bag, role: Role, named: &Option<String>) -> Result<Option<usize>, ImportError> {
    let malformed = |message: String| ImportError::Malformed { path: bag.file.clone(), message };
    let fits = |t: &Topic| role.types().contains(&canonical(&t.msg_type).as_str());
    if let Some(name) = named {
        let Some(i) = bag.topics.iter().position(|t| &t.name == name) else {
            return Err(malformed(format!("no topic {name} (the bag has: {})", listing(&bag.topics))));
        };
        if !fits(&bag.topics[i]) {
            return Err(malformed(format!(
                "topic {name} is {}, {} takes {}",
                bag.topics[i].msg_type,
                role.option(),
                role.types().join(" or ")
            )));
        }
        return Ok(Some(i));
    }
    let found: Vec<usize> = (0..bag.topics.len()).filter(|&i| fits(&bag.topics[i])).collect();
    match found[..] {
        [] => Ok(None),
        [i] => Ok(Some(i)),
        _ => Err(malformed(format!(
            "several {} topics ({}): choose one with {}",
            role.types().join(" / "),
            found.iter().map(|&i| bag.topics[i].name.as_str()).collect::<Vec<_>>().join(", "),
            role.option()
        ))),
    }
}

/// A series being read: times in ns, sorted and shifted to seconds at the end.
struct Raw<const N: usize> {
    source: String,
    samples: Vec<(i64, [f64; N])>,
}

impl<const N: usize> Raw<N> {
    fn new(source: &str) -> Self {
        Self { source: source.to_string(), samples: Vec::new() }
    }

    fn finish(mut self, t0: i64) -> Series<N> {
        // Stamps may arrive out of order; a stable sort keeps equal stamps as written.
        self.samples.sort_by_key(|s| s.0);
        let mut s = Series::new(self.source);
        for (t, v) in self.samples {
            s.push((t - t0) as f64 * 1e-9, v);
        }
        s
    }
}

/// Reads the runs of a ROS 2 bag into streams in pinc's frames. `commands_to_input` turns
/// one message of thruster commands (index `c - 1` is channel `c`) into the body input; it is
/// needed only when the input comes from an outputs topic.
///
/// # Errors
/// The bag cannot be read; a topic named in `opts` is missing or of the wrong type (the
/// error lists every topic with its type); several topics fit a role left to the default;
/// the bag has no state or no input topic; a message does not decode; a quaternion is not of
/// unit length (topic and time named); a wrench is in a world frame.
pub fn read_ros2(
    path: &Path,
    opts: &Ros2Options,
    commands_to_input: Option<CommandsToInput<'_>>,
) -> Result<StreamSet, ImportError> {
    let bag = Bag::open(path)?;
    let malformed = |message: String| ImportError::Malformed { path: bag.file.clone(), message };
    let odometry = select(&bag, Role::Odometry, &opts.odometry_topic)?;
    let pose = select(&bag, Role::Pose, &opts.pose_topic)?;
    let twist = select(&bag, Role::Twist, &opts.twist_topic)?;
    let wrench = select(&bag, Role::Wrench, &opts.wrench_topic)?;
    let outputs = select(&bag, Role::Outputs, &opts.outputs_topic)?;

    // A topic named in the options wins; by default odometry comes first.
    let pose = pose.filter(|_| opts.pose_topic.is_some() || odometry.is_none());
    let twist = twist.filter(|_| opts.twist_topic.is_some() || odometry.is_none());
    let odometry = odometry.filter(|_| pose.is_none() || twist.is_none());
    if odometry.is_none() && pose.is_none() && twist.is_none() {
        return Err(malformed(format!(
            "no state topic: none of type {ODOMETRY}, {POSE} or {TWIST} (the bag has: {})",
            listing(&bag.topics)
        )));
    }
    if opts.wrench_topic.is_some() && opts.outputs_topic.is_some() {
        return Err(ImportError::Unusable("--wrench-topic and --outputs-topic both name an input: give one".into()));
    }
    let wrench = wrench.filter(|_| opts.outputs_topic.is_none());
    let outputs = outputs.filter(|_| wrench.is_none());
    if wrench.is_none() && outputs.is_none() {
        return Err(malformed(format!(
            "no input topic: none of type {WRENCH}, {RCOUT} or {ACTUATOR_OUTPUTS} (the bag has: {})",
            listing(&bag.topics)
        )));
    }
    let convert = match (outputs, commands_to_input) {
        (Some(i), None) => {
            return Err(ImportError::Unusable(format!(
                "the input comes from thruster outputs ({}), which need the vehicle's thrusters (a vehicle file)",
                bag.topics[i].name
            )));
        }
        (_, c) => c,
    };

    let mut wanted = vec![false; bag.topics.len()];
    for i in [odometry, pose, twist, wrench, outputs].into_iter().flatten() {
        let t = &bag.topics[i];
        if t.encoding != "cdr" {
            return Err(malformed(format!("topic {}: serialization {:?}, only cdr is read", t.name, t.encoding)));
        }
        wanted[i] = true;
    }
    let name = |i: Option<usize>| i.map(|i| bag.topics[i].name.as_str()).unwrap_or("");
    let mut position = Raw::<3>::new(name(pose.or(odometry)));
    let mut att = Raw::<3>::new(name(pose.or(odometry)));
    let mut vel_body = Raw::<3>::new(name(twist.or(odometry)));
    let mut vel_ned = Raw::<3>::new(name(twist));
    let mut yaw_rate = Raw::<1>::new(name(twist.or(odometry)));
    let mut input = Raw::<4>::new(name(wrench.or(outputs)));

    let mut t0 = i64::MAX;
    let mut frames_used = BTreeSet::new();
    let mut zero_stamps = vec![0usize; bag.topics.len()];
    let world_over = opts.world_frame;
    let body_over = opts.body_frame;
    let mut counts = vec![0usize; bag.topics.len()];
    bag.for_each(&wanted, &mut |i, recv, data| {
        t0 = t0.min(recv);
        counts[i] += 1;
        let topic = &bag.topics[i].name;
        let at = |m: String| malformed(format!("{topic} at receive time {recv} ns: {m}"));
        let mut stamp_of = |h: &messages::Header| {
            h.stamp.nanos().unwrap_or_else(|| {
                zero_stamps[i] += 1;
                recv
            })
        };
        let quat = |q: &messages::Quaternion, stamp: i64| {
            let n = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
            if (n - 1.0).abs() > 1e-3 {
                return Err(malformed(format!(
                    "{topic} at stamp {stamp} ns: orientation quaternion of norm {n:.6}, not a rotation"
                )));
            }
            Ok([q.x, q.y, q.z, q.w])
        };
        if Some(i) == odometry {
            let m: messages::Odometry = decode(data).map_err(at)?;
            let t = stamp_of(&m.header);
            let w = world_of(&m.header.frame_id, world_over);
            let b = body_of(&m.child_frame_id, w, body_over);
            frames_used.insert(format!(
                "{topic}: frame_id {:?} read as {w}, child_frame_id {:?} as {b}",
                m.header.frame_id, m.child_frame_id
            ));
            if pose.is_none() {
                let q = quat(&m.pose.pose.orientation, t)?;
                position.samples.push((t, rotate(&to_ned(w), m.pose.pose.position.array())));
                att.samples.push((t, attitude(q, w, b)));
            }
            if twist.is_none() {
                let frd = to_frd(b);
                vel_body.samples.push((t, rotate(&frd, m.twist.twist.linear.array())));
                yaw_rate.samples.push((t, [rotate(&frd, m.twist.twist.angular.array())[2]]));
            }
        } else if Some(i) == pose {
            let m: messages::PoseStamped = decode(data).map_err(at)?;
            let t = stamp_of(&m.header);
            let w = world_of(&m.header.frame_id, world_over);
            let b = body_over.unwrap_or(partner(w));
            frames_used
                .insert(format!("{topic}: frame_id {:?} read as {w}, the body (unnamed) as {b}", m.header.frame_id));
            let q = quat(&m.pose.orientation, t)?;
            position.samples.push((t, rotate(&to_ned(w), m.pose.position.array())));
            att.samples.push((t, attitude(q, w, b)));
        } else if Some(i) == twist {
            let m: messages::TwistStamped = decode(data).map_err(at)?;
            let t = stamp_of(&m.header);
            let frame = &m.header.frame_id;
            if is_world(frame) {
                let w = world_of(frame, world_over);
                frames_used.insert(format!(
                    "{topic}: frame_id {frame:?} read as world {w}; yaw rate is the rate about the world's down axis"
                ));
                let ned = to_ned(w);
                vel_ned.samples.push((t, rotate(&ned, m.twist.linear.array())));
                yaw_rate.samples.push((t, [rotate(&ned, m.twist.angular.array())[2]]));
            } else {
                let b = body_of(frame, world_over.unwrap_or(WorldFrame::Enu), body_over);
                frames_used.insert(format!("{topic}: frame_id {frame:?} read as body {b}"));
                let frd = to_frd(b);
                vel_body.samples.push((t, rotate(&frd, m.twist.linear.array())));
                yaw_rate.samples.push((t, [rotate(&frd, m.twist.angular.array())[2]]));
            }
        } else if Some(i) == wrench {
            let m: messages::WrenchStamped = decode(data).map_err(at)?;
            let t = stamp_of(&m.header);
            let frame = &m.header.frame_id;
            if is_world(frame) {
                return Err(at(format!("wrench in the world frame {frame:?}: only body-frame wrenches are read")));
            }
            let b = body_of(frame, world_over.unwrap_or(WorldFrame::Enu), body_over);
            frames_used.insert(format!("{topic}: frame_id {frame:?} read as body {b}"));
            let frd = to_frd(b);
            let f = rotate(&frd, m.wrench.force.array());
            let n = rotate(&frd, m.wrench.torque.array());
            input.samples.push((t, [f[0], f[1], f[2], n[2]]));
        } else if Some(i) == outputs {
            let to_input = convert.ok_or_else(|| at("thruster outputs need the vehicle's thrusters".into()))?;
            let (t, commands): (i64, Vec<f64>) = if canonical(&bag.topics[i].msg_type) == RCOUT {
                let m: messages::RcOut = decode(data).map_err(at)?;
                (stamp_of(&m.header), m.channels.iter().map(|&c| f64::from(c)).collect())
            } else {
                let m: messages::ActuatorOutputs = decode(data).map_err(at)?;
                let n = (m.noutputs as usize).min(m.output.len());
                (recv, m.output[..n].iter().map(|&c| f64::from(c)).collect())
            };
            let u = to_input(&commands);
            input.samples.push((t, [u[0], u[1], u[2], u[3]]));
        }
        Ok(())
    })?;

    for (i, t) in bag.topics.iter().enumerate() {
        if wanted[i] && counts[i] == 0 {
            return Err(malformed(format!("topic {} ({}) has no messages", t.name, t.msg_type)));
        }
    }
    let mut notes = vec![format!(
        "time: header.stamp in s from the first receive time read ({} ns since the epoch)",
        if t0 == i64::MAX { 0 } else { t0 }
    )];
    notes.extend(frames_used);
    for (i, &n) in zero_stamps.iter().enumerate() {
        if n > 0 {
            notes.push(format!("{}: {n} messages with a zero header.stamp took the receive time", bag.topics[i].name));
        }
    }
    if let Some(i) = outputs {
        let t = &bag.topics[i];
        if canonical(&t.msg_type) == ACTUATOR_OUTPUTS {
            notes.push(format!(
                "{}: timed by the receive time (its timestamp counts from the autopilot's boot)",
                t.name
            ));
        }
        notes.push(format!("{}: thruster commands turned into the input by the vehicle's thrusters", t.name));
    }
    if let Some(i) = odometry {
        let t = &bag.topics[i].name;
        let parts = [(pose.is_none(), "position and attitude"), (twist.is_none(), "body velocity and yaw rate")];
        let used: Vec<&str> = parts.iter().filter(|p| p.0).map(|p| p.1).collect();
        notes.push(format!("{t}: {} (yaw rate: the body z rate, equal for small roll and pitch)", used.join(", ")));
    }
    let t0 = if t0 == i64::MAX { 0 } else { t0 };
    let some = |s: Series<3>| (!s.is_empty()).then_some(s);
    let yaw_rate = yaw_rate.finish(t0);
    let input = input.finish(t0);
    Ok(StreamSet {
        position: some(position.finish(t0)),
        depth: None,
        attitude: some(att.finish(t0)),
        velocity_ned: some(vel_ned.finish(t0)),
        velocity_body: some(vel_body.finish(t0)),
        yaw_rate: (!yaw_rate.is_empty()).then_some(yaw_rate),
        input: (!input.is_empty()).then_some(input),
        notes,
    })
}
