//! pinc inside Cockpit, the owners' ground station: the extras file BlueOS's `register_service`
//! points Cockpit at (Cockpit 1.18 and later, BlueOS 1.4 and later; docs/PILOT.md). Cockpit
//! reads it from the extension's own address (`/extensionv2/pinc` beside Cockpit's, so the same
//! origin), and offers the page as a widget, the commands as actions, and a joystick mapping
//! for them.

use serde_json::{Value, json};

/// Where `register_service` says the extras are.
pub const EXTRAS_PATH: &str = "/cockpit_extras.json";

/// The extras: the page as an iframe widget, "hold here" (the depth, heading and position at the
/// press), "resume" (the vehicle back to the pilot) and STOP as HTTP actions carrying the page's
/// token (stable across restarts: the data folder's), and a joystick suggestion for
/// them. Cockpit checks the file as a whole: one field wrong and it drops all of it.
pub fn extras(token: &str) -> Value {
    let version = env!("CARGO_PKG_VERSION");
    // Cockpit fills `{{ vehicle-address }}`; BlueOS serves the extension under its name.
    let action = |id: &str, name: &str, path: &str, what: &str| {
        json!({
            "id": id,
            "name": name,
            "type": "http-request",
            "version": version,
            "config": {
                "name": name,
                "url": format!("http://{{{{ vehicle-address }}}}/extensionv2/pinc/api/{path}"),
                "method": "POST",
                "headers": {"Content-Type": "application/json", "X-Pinc-Token": token},
                "urlParams": {},
                "body": what,
            },
        })
    };
    let suggestion = |id: &str, action_id: &str, name: &str, button: u32, what: &str| {
        json!({
            "id": id,
            "actionProtocol": "cockpit-action",
            "actionName": name,
            "actionId": action_id,
            "button": button,
            "modifierKey": "shift",
            "description": what,
        })
    };
    json!({
        "targetSystem": "Cockpit",
        "targetCockpitApiVersion": "1.0.0",
        "widgets": [{
            "name": "pinc",
            "iframeUrl": "/",
            "iconUrl": "/icon.svg",
            "useExtensionPathAsBaseUrl": true,
            "version": version,
        }],
        "actions": [
            action("pinc-hold-here", "pinc: hold here", "hold", "{}"),
            action("pinc-resume", "pinc: resume", "resume", "{}"),
            action("pinc-stop", "pinc: STOP", "stop", "{}"),
        ],
        "joystickSuggestions": [{
            "id": "pinc-buttons",
            "name": "pinc: hold here, resume and STOP",
            "description": "pinc's hold, resume and STOP on three buttons with shift",
            "targetVehicleTypes": ["MAV_TYPE_SUBMARINE"],
            "version": version,
            "buttonMappingSuggestions": [
                suggestion("pinc-suggest-hold", "pinc-hold-here", "pinc: hold here", 2, "hold the depth, heading and position now"),
                suggestion("pinc-suggest-resume", "pinc-resume", "pinc: resume", 3, "the vehicle back to the pilot as they had it"),
                suggestion("pinc-suggest-stop", "pinc-stop", "pinc: STOP", 1, "neutral and disarm"),
            ],
        }],
    })
}

/// The widget's icon: a hull over a wave (drawn here, no file to ship).
pub const ICON_SVG: &str = r##"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 24 24"><path d="M3 11h13l4 3H3z" fill="#1e6bd6"/><path d="M2 18c2-2 4 2 6 0s4 2 6 0 4 2 6 0" stroke="#1e6bd6" stroke-width="2" fill="none"/></svg>"##;
