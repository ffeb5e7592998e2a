//! The ROS 2 messages read, as serde structs in their CDR field order (`cdr-encoding` does
//! the decoding), and the encapsulation header every serialized message starts with.

use serde::Deserialize;
use serde::de::{self, Deserializer, SeqAccess, Visitor};

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds, or `None` for the zero stamp (not filled in by the publisher).
    pub fn nanos(&self) -> Option<i64> {
        let ns = i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec);
        (ns != 0).then_some(ns)
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/msg/Vector3` and `Point`.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl Vector3 {
    pub fn array(&self) -> [f64; 3] {
        [self.x, self.y, self.z]
    }
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Deserialize)]
pub struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/Twist`.
#[derive(Debug, Clone, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// `geometry_msgs/msg/Wrench`.
#[derive(Debug, Clone, Deserialize)]
pub struct Wrench {
    pub force: Vector3,
    pub torque: Vector3,
}

/// A fixed-size array of `N` doubles (CDR writes no length): serde derives arrays only up to
/// 32, and a covariance has 36.
#[derive(Debug, Clone)]
pub struct Fixed<const N: usize>(pub [f64; N]);

impl<'de, const N: usize> Deserialize<'de> for Fixed<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<const N: usize>;
        impl<'de, const N: usize> Visitor<'de> for V<N> {
            type Value = Fixed<N>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "{N} doubles")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Fixed<N>, A::Error> {
                let mut out = [0.0; N];
                for (i, o) in out.iter_mut().enumerate() {
                    *o = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                Ok(Fixed(out))
            }
        }
        d.deserialize_tuple(N, V::<N>)
    }
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Debug, Clone, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    #[allow(dead_code)] // decoded for the layout only
    pub covariance: Fixed<36>,
}

/// `geometry_msgs/msg/TwistWithCovariance`.
#[derive(Debug, Clone, Deserialize)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    #[allow(dead_code)] // decoded for the layout only
    pub covariance: Fixed<36>,
}

/// `nav_msgs/msg/Odometry`: pose in `header.frame_id`, twist in `child_frame_id`.
#[derive(Debug, Clone, Deserialize)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Debug, Clone, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `geometry_msgs/msg/TwistStamped`.
#[derive(Debug, Clone, Deserialize)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}

/// `geometry_msgs/msg/WrenchStamped`.
#[derive(Debug, Clone, Deserialize)]
pub struct WrenchStamped {
    pub header: Header,
    pub wrench: Wrench,
}

/// `mavros_msgs/msg/RCOut`: PWM per output channel (us).
#[derive(Debug, Clone, Deserialize)]
pub struct RcOut {
    pub header: Header,
    pub channels: Vec<u16>,
}

/// `px4_msgs/msg/ActuatorOutputs`: 16 outputs, the first `noutputs` in use; `timestamp` is
/// microseconds since the autopilot booted.
#[derive(Debug, Clone, Deserialize)]
pub struct ActuatorOutputs {
    #[allow(dead_code)] // decoded for the layout only: the receive time is used
    pub timestamp: u64,
    pub noutputs: u32,
    pub output: [f32; 16],
}

/// Decodes one serialized message: a 4-byte encapsulation header (plain CDR, little or big
/// endian) and the CDR body, aligned from the end of the header.
pub fn decode<T: for<'de> Deserialize<'de>>(data: &[u8]) -> Result<T, String> {
    use byteorder::{BigEndian, LittleEndian};
    if data.len() < 4 {
        return Err(format!("{} bytes, shorter than the CDR header", data.len()));
    }
    let body = &data[4..];
    let decoded = match (data[0], data[1]) {
        (0, 1) => cdr_encoding::from_bytes::<T, LittleEndian>(body),
        (0, 0) => cdr_encoding::from_bytes::<T, BigEndian>(body),
        (a, b) => return Err(format!("encapsulation {a:#04x} {b:#04x}, only plain CDR (0x0000, 0x0001) is read")),
    };
    decoded.map(|(v, _)| v).map_err(|e| format!("not a valid CDR message of this type: {e}"))
}
