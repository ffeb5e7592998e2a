//! The live view of a run: every message written to the run's MCAP log, served as it is
//! written over Foxglove's WebSocket protocol (the Foxglove SDK's server), so an owner at the
//! tether opens the run in Foxglove while it happens, with the same topics, schemas and times
//! as the file. Bound to loopback unless an address is given. Feature `live-view`.

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer, WebSocketServerHandle};
use std::collections::BTreeMap;
use std::sync::Arc;

/// The server could not start.
#[derive(Debug, thiserror::Error)]
#[error("live view on {address}: {detail}")]
pub struct LiveViewError {
    /// The address asked for.
    pub address: String,
    /// What went wrong.
    pub detail: String,
}

/// A running live view: the server and one channel per log topic.
pub struct LiveView {
    context: Arc<Context>,
    server: Option<WebSocketServerHandle>,
    channels: BTreeMap<u16, Arc<RawChannel>>,
}

impl LiveView {
    /// Starts the server on `address` (`HOST:PORT`, or a port alone for loopback; port 0
    /// picks a free one).
    ///
    /// # Errors
    /// A malformed address, or the server cannot bind it.
    pub fn start(address: &str) -> Result<Self, LiveViewError> {
        let err = |detail: String| LiveViewError { address: address.to_string(), detail };
        let (host, port) = match address.rsplit_once(':') {
            Some((h, p)) => (h.to_string(), p),
            None => ("127.0.0.1".to_string(), address),
        };
        let port: u16 = port.parse().map_err(|_| err(format!("'{port}' is not a port number")))?;
        // A context of its own: the run's channels and nothing else.
        let context = Context::new();
        let server = WebSocketServer::new()
            .name(concat!("pinc ", env!("CARGO_PKG_VERSION")))
            .context(&context)
            .bind(host, port)
            .start_blocking()
            .map_err(|e| err(e.to_string()))?;
        Ok(Self { context, server: Some(server), channels: BTreeMap::new() })
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.server.as_ref().map_or(0, WebSocketServerHandle::port)
    }

    /// Advertises the log's channel `id` on `topic`, JSON messages of JSON schema `schema`.
    ///
    /// # Errors
    /// The SDK refuses the channel (a topic advertised twice with another schema).
    pub fn add_channel(&mut self, id: u16, topic: &str, schema: &str, schema_json: &[u8]) -> Result<(), String> {
        let channel = ChannelBuilder::new(topic)
            .message_encoding("json")
            .schema(Schema::new(schema, "jsonschema", schema_json.to_vec()))
            .context(&self.context)
            .build_raw()
            .map_err(|e| format!("live view channel {topic}: {e}"))?;
        self.channels.insert(id, channel);
        Ok(())
    }

    /// Sends one message of channel `id` at log time `log_time_ns` (the MCAP record's) to
    /// every client subscribed to it.
    pub fn log(&self, id: u16, log_time_ns: u64, data: &[u8]) {
        if let Some(c) = self.channels.get(&id) {
            c.log_with_meta(data, PartialMetadata::with_log_time(log_time_ns));
        }
    }

    /// Stops the server once every queued message has gone out.
    pub fn stop(mut self) {
        for c in self.channels.values() {
            c.close();
        }
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
    }
}
