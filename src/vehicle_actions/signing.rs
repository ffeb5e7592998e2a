//! `pinc vehicle setup-signing`.

use super::SetupSigningArgs;
use crate::link::SigningKey;
use crate::link::cli::open;
use mavlink::dialects::ardupilotmega::MavMessage;
use std::time::Duration;
/// `pinc vehicle setup-signing`: SETUP_SIGNING three times (it has no acknowledgement), then a
/// second link that signs with the new key must hear the autopilot's signed heartbeat.
pub(super) fn run_setup_signing(a: SetupSigningArgs) -> Result<(), String> {
    let key = SigningKey::load(&a.key).map_err(|e| e.to_string())?;
    let (link, autopilot, _) = open(&a.link.connect, &a.link, |_| {})?;
    let message = MavMessage::SETUP_SIGNING(key.setup_message(autopilot.system_id, autopilot.component_id));
    for _ in 0..3 {
        link.send(&message).map_err(|e| e.to_string())?;
        std::thread::sleep(Duration::from_millis(100));
    }
    drop(link);
    std::thread::sleep(Duration::from_millis(500));
    let mut options = a.link.options.clone();
    options.signing_key = Some(a.key.clone());
    let checked = open(&a.link.connect, &options, |_| {});
    match checked {
        Ok((_, ap, _)) => {
            println!(
                "signing set up: system {} answers signed with the key of {}; connect with --signing-key {}",
                ap.system_id,
                a.key.display(),
                a.key.display()
            );
            Ok(())
        }
        Err(e) => Err(format!("SETUP_SIGNING was sent but the autopilot did not answer signed with the new key: {e}")),
    }
}
