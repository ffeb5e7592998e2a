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

/// The topic read for each role, after the precedence rules: a topic named in the options
/// wins, by default odometry comes before a pose and a twist, a wrench before thruster outputs.
#[derive(Clone, Copy)]
struct Chosen {
    odometry: Option<usize>,
    pose: Option<usize>,
    twist: Option<usize>,
    wrench: Option<usize>,
    outputs: Option<usize>,
}

impl Chosen {
    /// Chooses the topics of `bag` for `opts`. `has_converter`: thruster commands can be
    /// turned into the input.
    ///
    /// # Errors
    /// As [`select`]; no state topic; two inputs named; no input topic; thruster outputs
    /// without a converter.
    fn new(bag: &Bag, opts: &Ros2Options, has_converter: bool) -> Result<Self, ImportError> {
        let malformed = |message: String| ImportError::Malformed { path: bag.file.clone(), message };
        let odometry = select(bag, Role::Odometry, &opts.odometry_topic)?;
        let pose = select(bag, Role::Pose, &opts.pose_topic)?;
        let twist = select(bag, Role::Twist, &opts.twist_topic)?;
        let wrench = select(bag, Role::Wrench, &opts.wrench_topic)?;
        let outputs = select(bag, Role::Outputs, &opts.outputs_topic)?;

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
            return Err(ImportError::Unusable(
                "--wrench-topic and --outputs-topic both name an input: give one".into(),
            ));
        }
        let wrench = wrench.filter(|_| opts.outputs_topic.is_none());
        let outputs = outputs.filter(|_| wrench.is_none());
        if wrench.is_none() && outputs.is_none() {
            return Err(malformed(format!(
                "no input topic: none of type {WRENCH}, {RCOUT} or {ACTUATOR_OUTPUTS} (the bag has: {})",
                listing(&bag.topics)
            )));
        }
        if let (Some(i), false) = (outputs, has_converter) {
            return Err(ImportError::Unusable(format!(
                "the input comes from thruster outputs ({}), which need the vehicle's thrusters (a vehicle file)",
                bag.topics[i].name
            )));
        }
        Ok(Self { odometry, pose, twist, wrench, outputs })
    }

    /// Which topics of `bag` are read (by topic index).
    ///
    /// # Errors
    /// A chosen topic whose serialization is not CDR.
    fn wanted(self, bag: &Bag) -> Result<Vec<bool>, ImportError> {
        let mut wanted = vec![false; bag.topics.len()];
        for i in [self.odometry, self.pose, self.twist, self.wrench, self.outputs].into_iter().flatten() {
            let t = &bag.topics[i];
            if t.encoding != "cdr" {
                return Err(ImportError::Malformed {
                    path: bag.file.clone(),
                    message: format!("topic {}: serialization {:?}, only cdr is read", t.name, t.encoding),
                });
            }
            wanted[i] = true;
        }
        Ok(wanted)
    }
}

/// One message as the bag gives it.
struct Message<'m> {
    /// The topic's index in the bag and its name.
    i: usize,
    topic: &'m str,
    /// Receive time (ns since the epoch).
    recv: i64,
    data: &'m [u8],
    file: &'m Path,
}

impl Message<'_> {
    /// An error about this message, naming its topic and receive time.
    fn error(&self, m: String) -> ImportError {
        ImportError::Malformed {
            path: self.file.to_path_buf(),
            message: format!("{} at receive time {} ns: {m}", self.topic, self.recv),
        }
    }

    /// The message decoded as `T`.
    fn decode<T: for<'de> Deserialize<'de>>(&self) -> Result<T, ImportError> {
        decode(self.data).map_err(|m| self.error(m))
    }

    /// The quaternion `[x, y, z, w]` of a message stamped `stamp`.
    ///
    /// # Errors
    /// Not of unit length (within 1e-3), naming the topic and the stamp.
    fn rotation(&self, q: &messages::Quaternion, stamp: i64) -> Result<[f64; 4], ImportError> {
        let n = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
        if (n - 1.0).abs() > 1e-3 {
            return Err(ImportError::Malformed {
                path: self.file.to_path_buf(),
                message: format!(
                    "{} at stamp {stamp} ns: orientation quaternion of norm {n:.6}, not a rotation",
                    self.topic
                ),
            });
        }
        Ok([q.x, q.y, q.z, q.w])
    }
}

/// What the messages have given so far: the streams (times in ns), the earliest receive time,
/// the frames as read, and the counts per topic that the notes and checks need.
struct Reading<'a> {
    chosen: Chosen,
    opts: &'a Ros2Options,
    convert: Option<CommandsToInput<'a>>,
    position: Raw<3>,
    att: Raw<3>,
    vel_body: Raw<3>,
    vel_ned: Raw<3>,
    yaw_rate: Raw<1>,
    input: Raw<4>,
    /// The earliest receive time (ns), `i64::MAX` before the first message.
    t0: i64,
    frames_used: BTreeSet<String>,
    /// Per topic: messages whose zero `header.stamp` took the receive time; messages read.
    zero_stamps: Vec<usize>,
    counts: Vec<usize>,
}

impl<'a> Reading<'a> {
    /// Empty streams named after the topics they come from.
    fn new(bag: &Bag, chosen: Chosen, opts: &'a Ros2Options, convert: Option<CommandsToInput<'a>>) -> Self {
        let name = |i: Option<usize>| i.map(|i| bag.topics[i].name.as_str()).unwrap_or("");
        let Chosen { odometry, pose, twist, wrench, outputs } = chosen;
        Self {
            chosen,
            opts,
            convert,
            position: Raw::new(name(pose.or(odometry))),
            att: Raw::new(name(pose.or(odometry))),
            vel_body: Raw::new(name(twist.or(odometry))),
            vel_ned: Raw::new(name(twist)),
            yaw_rate: Raw::new(name(twist.or(odometry))),
            input: Raw::new(name(wrench.or(outputs))),
            t0: i64::MAX,
            frames_used: BTreeSet::new(),
            zero_stamps: vec![0; bag.topics.len()],
            counts: vec![0; bag.topics.len()],
        }
    }

    /// One message of a wanted topic, read for the role its topic was chosen for.
    fn message(&mut self, bag: &Bag, m: &Message<'_>) -> Result<(), ImportError> {
        self.t0 = self.t0.min(m.recv);
        self.counts[m.i] += 1;
        let c = self.chosen;
        if Some(m.i) == c.odometry {
            self.odometry(m)
        } else if Some(m.i) == c.pose {
            self.pose(m)
        } else if Some(m.i) == c.twist {
            self.twist(m)
        } else if Some(m.i) == c.wrench {
            self.wrench(m)
        } else if Some(m.i) == c.outputs {
            self.outputs(m, canonical(&bag.topics[m.i].msg_type) == RCOUT)
        } else {
            Ok(())
        }
    }

    /// A header's stamp (ns), or the receive time where it is zero (counted).
    fn stamp(&mut self, m: &Message<'_>, h: &messages::Header) -> i64 {
        h.stamp.nanos().unwrap_or_else(|| {
            self.zero_stamps[m.i] += 1;
            m.recv
        })
    }

    /// Odometry: position and attitude unless a pose topic replaces them, body velocity and
    /// yaw rate unless a twist topic does.
    fn odometry(&mut self, m: &Message<'_>) -> Result<(), ImportError> {
        let o: messages::Odometry = m.decode()?;
        let t = self.stamp(m, &o.header);
        let w = world_of(&o.header.frame_id, self.opts.world_frame);
        let b = body_of(&o.child_frame_id, w, self.opts.body_frame);
        self.frames_used.insert(format!(
            "{}: frame_id {:?} read as {w}, child_frame_id {:?} as {b}",
            m.topic, o.header.frame_id, o.child_frame_id
        ));
        if self.chosen.pose.is_none() {
            let q = m.rotation(&o.pose.pose.orientation, t)?;
            self.position.samples.push((t, rotate(&to_ned(w), o.pose.pose.position.array())));
            self.att.samples.push((t, attitude(q, w, b)));
        }
        if self.chosen.twist.is_none() {
            let frd = to_frd(b);
            self.vel_body.samples.push((t, rotate(&frd, o.twist.twist.linear.array())));
            self.yaw_rate.samples.push((t, [rotate(&frd, o.twist.twist.angular.array())[2]]));
        }
        Ok(())
    }

    /// A pose: position and attitude (the body frame is unnamed: the world's partner).
    fn pose(&mut self, m: &Message<'_>) -> Result<(), ImportError> {
        let p: messages::PoseStamped = m.decode()?;
        let t = self.stamp(m, &p.header);
        let w = world_of(&p.header.frame_id, self.opts.world_frame);
        let b = self.opts.body_frame.unwrap_or(partner(w));
        self.frames_used
            .insert(format!("{}: frame_id {:?} read as {w}, the body (unnamed) as {b}", m.topic, p.header.frame_id));
        let q = m.rotation(&p.pose.orientation, t)?;
        self.position.samples.push((t, rotate(&to_ned(w), p.pose.position.array())));
        self.att.samples.push((t, attitude(q, w, b)));
        Ok(())
    }

    /// A twist: in a world frame the NED velocity, in a body frame the body velocity; the yaw
    /// rate about the frame's vertical axis either way.
    fn twist(&mut self, m: &Message<'_>) -> Result<(), ImportError> {
        let tw: messages::TwistStamped = m.decode()?;
        let t = self.stamp(m, &tw.header);
        let (frame, topic) = (&tw.header.frame_id, m.topic);
        if is_world(frame) {
            let w = world_of(frame, self.opts.world_frame);
            self.frames_used.insert(format!(
                "{topic}: frame_id {frame:?} read as world {w}; yaw rate is the rate about the world's down axis"
            ));
            let ned = to_ned(w);
            self.vel_ned.samples.push((t, rotate(&ned, tw.twist.linear.array())));
            self.yaw_rate.samples.push((t, [rotate(&ned, tw.twist.angular.array())[2]]));
        } else {
            let b = body_of(frame, self.opts.world_frame.unwrap_or(WorldFrame::Enu), self.opts.body_frame);
            self.frames_used.insert(format!("{topic}: frame_id {frame:?} read as body {b}"));
            let frd = to_frd(b);
            self.vel_body.samples.push((t, rotate(&frd, tw.twist.linear.array())));
            self.yaw_rate.samples.push((t, [rotate(&frd, tw.twist.angular.array())[2]]));
        }
        Ok(())
    }

    /// A wrench in a body frame: the input.
    ///
    /// # Errors
    /// A wrench in a world frame.
    fn wrench(&mut self, m: &Message<'_>) -> Result<(), ImportError> {
        let wr: messages::WrenchStamped = m.decode()?;
        let t = self.stamp(m, &wr.header);
        let frame = &wr.header.frame_id;
        if is_world(frame) {
            return Err(m.error(format!("wrench in the world frame {frame:?}: only body-frame wrenches are read")));
        }
        let b = body_of(frame, self.opts.world_frame.unwrap_or(WorldFrame::Enu), self.opts.body_frame);
        self.frames_used.insert(format!("{}: frame_id {frame:?} read as body {b}", m.topic));
        let frd = to_frd(b);
        let f = rotate(&frd, wr.wrench.force.array());
        let n = rotate(&frd, wr.wrench.torque.array());
        self.input.samples.push((t, [f[0], f[1], f[2], n[2]]));
        Ok(())
    }

    /// Thruster commands (`RCOut` when `rc_out`, else PX4's `ActuatorOutputs`, timed by the
    /// receive time) through the converter: the input.
    fn outputs(&mut self, m: &Message<'_>, rc_out: bool) -> Result<(), ImportError> {
        let to_input = self.convert.ok_or_else(|| m.error("thruster outputs need the vehicle's thrusters".into()))?;
        let (t, commands): (i64, Vec<f64>) = if rc_out {
            let o: messages::RcOut = m.decode()?;
            (self.stamp(m, &o.header), o.channels.iter().map(|&c| f64::from(c)).collect())
        } else {
            let o: messages::ActuatorOutputs = m.decode()?;
            let n = (o.noutputs as usize).min(o.output.len());
            (m.recv, o.output[..n].iter().map(|&c| f64::from(c)).collect())
        };
        let u = to_input(&commands);
        self.input.samples.push((t, [u[0], u[1], u[2], u[3]]));
        Ok(())
    }

    /// Every wanted topic gave a message.
    ///
    /// # Errors
    /// The first wanted topic without one.
    fn check_counts(&self, bag: &Bag, wanted: &[bool]) -> Result<(), ImportError> {
        for (i, t) in bag.topics.iter().enumerate() {
            if wanted[i] && self.counts[i] == 0 {
                return Err(ImportError::Malformed {
                    path: bag.file.clone(),
                    message: format!("topic {} ({}) has no messages", t.name, t.msg_type),
                });
            }
        }
        Ok(())
    }

    /// The notes: the time base, the frames as read, the zero stamps, the outputs' timing and
    /// conversion, what the odometry gave.
    fn notes(&self, bag: &Bag) -> Vec<String> {
        let mut notes = vec![format!(
            "time: header.stamp in s from the first receive time read ({} ns since the epoch)",
            if self.t0 == i64::MAX { 0 } else { self.t0 }
        )];
        notes.extend(self.frames_used.iter().cloned());
        for (i, &n) in self.zero_stamps.iter().enumerate() {
            if n > 0 {
                notes.push(format!(
                    "{}: {n} messages with a zero header.stamp took the receive time",
                    bag.topics[i].name
                ));
            }
        }
        if let Some(i) = self.chosen.outputs {
            let t = &bag.topics[i];
            if canonical(&t.msg_type) == ACTUATOR_OUTPUTS {
                notes.push(format!(
                    "{}: timed by the receive time (its timestamp counts from the autopilot's boot)",
                    t.name
                ));
            }
            notes.push(format!("{}: thruster commands turned into the input by the vehicle's thrusters", t.name));
        }
        if let Some(i) = self.chosen.odometry {
            let t = &bag.topics[i].name;
            let parts = [
                (self.chosen.pose.is_none(), "position and attitude"),
                (self.chosen.twist.is_none(), "body velocity and yaw rate"),
            ];
            let used: Vec<&str> = parts.iter().filter(|p| p.0).map(|p| p.1).collect();
            notes.push(format!("{t}: {} (yaw rate: the body z rate, equal for small roll and pitch)", used.join(", ")));
        }
        notes
    }

    /// The streams on seconds from the earliest receive time, each sorted by time; a stream
    /// without samples is left out.
    fn finish(self, notes: Vec<String>) -> StreamSet {
        let t0 = if self.t0 == i64::MAX { 0 } else { self.t0 };
        let some = |s: Series<3>| (!s.is_empty()).then_some(s);
        let yaw_rate = self.yaw_rate.finish(t0);
        let input = self.input.finish(t0);
        StreamSet {
            position: some(self.position.finish(t0)),
            depth: None,
            attitude: some(self.att.finish(t0)),
            velocity_ned: some(self.vel_ned.finish(t0)),
            velocity_body: some(self.vel_body.finish(t0)),
            yaw_rate: (!yaw_rate.is_empty()).then_some(yaw_rate),
            input: (!input.is_empty()).then_some(input),
            notes,
        }
    }
}

/// Reads the runs of a ROS 2 bag into streams in pinc's frames. `commands_to_input` turns
/// one message of thruster commands (index `c - 1` is channel `c`) into the body input; it is
/// needed only when the input comes from an outputs topic.
///
/// The stages: the bag opened, the topic of each role chosen (`Chosen`) and checked before
/// any message is read, every message of those topics read in its role (`Reading`), each
/// topic checked for messages, the notes, the streams on one time base.
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
    let chosen = Chosen::new(&bag, opts, commands_to_input.is_some())?;
    let wanted = chosen.wanted(&bag)?;
    let mut reading = Reading::new(&bag, chosen, opts, commands_to_input);
    bag.for_each(&wanted, &mut |i, recv, data| {
        let m = Message { i, topic: &bag.topics[i].name, recv, data, file: &bag.file };
        reading.message(&bag, &m)
    })?;
    reading.check_counts(&bag, &wanted)?;
    let notes = reading.notes(&bag);
    Ok(reading.finish(notes))
}
