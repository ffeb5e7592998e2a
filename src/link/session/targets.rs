//! The autopilot's own controllers' targets (ALT_HOLD, GUIDED), one set per cycle.

use super::AutopilotHold;
use crate::link::drive::Drive;
use crate::link::safety::Trigger;
use mavlink::dialects::ardupilotmega::{
    AttitudeTargetTypemask, MavFrame, MavMessage, PositionTargetTypemask, SET_ATTITUDE_TARGET_DATA,
    SET_POSITION_TARGET_GLOBAL_INT_DATA, SET_POSITION_TARGET_LOCAL_NED_DATA,
};

/// The autopilot's targets for one cycle: depth and heading at `reference` (ALT_HOLD and
/// POSHOLD, which holds the position it entered at), or with the horizontal goal's position and
/// velocity (GUIDED), the depth's rate from the next reference.
pub(super) fn send_targets(
    drive: &Drive,
    hold: AutopilotHold,
    time_boot_ms: u32,
    reference: (f64, f64),
    depth_rate: f64,
    horizontal: crate::mpc::Horizontal,
) -> Result<(), Trigger> {
    let (system, component) = {
        let a = drive.autopilot();
        (a.system_id, a.component_id)
    };
    let (depth, heading) = reference;
    let link = drive.link();
    let sent = match hold {
        AutopilotHold::AltHold | AutopilotHold::PosHold => {
            // ArduSub 4.x in ALT_HOLD: z only (type_mask 3579), `alt` metres up from the origin.
            let depth_target = MavMessage::SET_POSITION_TARGET_GLOBAL_INT(SET_POSITION_TARGET_GLOBAL_INT_DATA {
                time_boot_ms,
                target_system: system,
                target_component: component,
                coordinate_frame: MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
                type_mask: PositionTargetTypemask::from_bits_truncate(3579),
                lat_int: 0,
                lon_int: 0,
                alt: -depth as f32,
                vx: 0.0,
                vy: 0.0,
                vz: 0.0,
                afx: 0.0,
                afy: 0.0,
                afz: 0.0,
                yaw: 0.0,
                yaw_rate: 0.0,
            });
            // Attitude only, the throttle ignored (type_mask 71): ALT_HOLD keeps it 5 s.
            let (s, c) = (0.5 * heading).sin_cos();
            let heading_target = MavMessage::SET_ATTITUDE_TARGET(SET_ATTITUDE_TARGET_DATA {
                time_boot_ms,
                target_system: system,
                target_component: component,
                type_mask: AttitudeTargetTypemask::from_bits_truncate(71),
                q: [c as f32, 0.0, 0.0, s as f32],
                body_roll_rate: 0.0,
                body_pitch_rate: 0.0,
                body_yaw_rate: 0.0,
                thrust: 0.5,
            });
            link.send(&depth_target).and_then(|()| link.send(&heading_target))
        }
        AutopilotHold::Guided => {
            // Position, velocity and yaw (type_mask 2496: accelerations and yaw rate ignored),
            // which streams smoothly (2552 restarts the planner at every message).
            link.send(&MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
                time_boot_ms,
                target_system: system,
                target_component: component,
                coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
                type_mask: PositionTargetTypemask::from_bits_truncate(2496),
                x: horizontal.north as f32,
                y: horizontal.east as f32,
                z: depth as f32,
                vx: horizontal.velocity[0] as f32,
                vy: horizontal.velocity[1] as f32,
                vz: depth_rate as f32,
                afx: 0.0,
                afy: 0.0,
                afz: 0.0,
                yaw: heading as f32,
                yaw_rate: 0.0,
            }))
        }
    };
    sent.map_err(|e| Trigger::Link(e.to_string()))
}
