//! Connection addresses as MAVLink tools write them, mapped onto the `mavlink` crate's.
//!
//! Accepted forms (HOST may be a name, an IPv4 address or a bracketed IPv6 address):
//! - `udpin:HOST:PORT` (and `udp:HOST:PORT`, as MAVProxy and pymavlink read it): listen on
//!   HOST:PORT; replies go to whoever sent the last packet (ArduSub's companion and QGC
//!   links send to a listener on 14550);
//! - `udpout:HOST:PORT`: send to HOST:PORT from a free local port;
//! - `tcp:HOST:PORT` or `tcpout:HOST:PORT`: connect to a TCP server (ArduSub's simulator
//!   listens on 5760); `tcpin:HOST:PORT`: wait for one TCP client;
//! - `serial:DEVICE:BAUD`, `DEVICE:BAUD` or `DEVICE,BAUD` (as pymavlink writes it), with a
//!   DEVICE such as `/dev/ttyACM0` or `COM3`.

use std::fmt;
use std::str::FromStr;

/// A parsed connection address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkAddress {
    /// Listen for UDP packets on `HOST:PORT`.
    UdpIn(String),
    /// Send UDP packets to `HOST:PORT`.
    UdpOut(String),
    /// Connect to a TCP server at `HOST:PORT`.
    TcpOut(String),
    /// Accept one TCP client on `HOST:PORT`.
    TcpIn(String),
    /// A serial device at a baud rate.
    Serial {
        /// The device (`/dev/ttyACM0`, `COM3`).
        device: String,
        /// Bits per second.
        baud: u32,
    },
}

/// Why a connection address was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UrlError {
    /// Nothing was given.
    #[error("empty connection address; give e.g. udpin:0.0.0.0:14550")]
    Empty,
    /// The part before the first `:` is not a known transport.
    #[error(
        "{url:?}: unknown transport {scheme:?}; use udpin:, udp:, udpout:, tcp:, tcpout:, tcpin:, serial: or DEVICE:BAUD"
    )]
    UnknownScheme {
        /// The address.
        url: String,
        /// Its transport part.
        scheme: String,
    },
    /// A network address without `HOST:PORT`, or with a port that is not 1-65535.
    #[error("{url:?}: expected HOST:PORT after {scheme:?} with PORT in 1-65535, got {rest:?}")]
    BadHostPort {
        /// The address.
        url: String,
        /// Its transport part.
        scheme: String,
        /// What followed it.
        rest: String,
    },
    /// A serial address without a baud rate, or with one that is not a positive integer.
    #[error("{url:?}: expected a serial DEVICE:BAUD with BAUD a positive integer (e.g. /dev/ttyACM0:115200)")]
    BadSerial {
        /// The address.
        url: String,
    },
}

fn host_port(url: &str, scheme: &str, rest: &str) -> Result<String, UrlError> {
    let bad = || UrlError::BadHostPort { url: url.into(), scheme: scheme.into(), rest: rest.into() };
    let (host, port) = rest.rsplit_once(':').ok_or_else(bad)?;
    let port: u16 = port.parse().map_err(|_| bad())?;
    if host.is_empty() || port == 0 {
        return Err(bad());
    }
    Ok(format!("{host}:{port}"))
}

fn serial(url: &str, rest: &str) -> Result<LinkAddress, UrlError> {
    let bad = || UrlError::BadSerial { url: url.into() };
    let (device, baud) = rest.rsplit_once([':', ',']).ok_or_else(bad)?;
    let baud: u32 = baud.parse().map_err(|_| bad())?;
    if device.is_empty() || baud == 0 {
        return Err(bad());
    }
    Ok(LinkAddress::Serial { device: device.into(), baud })
}

/// A device path rather than a transport name: `/dev/...`, `COM3`.
fn looks_like_device(url: &str) -> bool {
    let upper = url.to_ascii_uppercase();
    url.starts_with('/') || (upper.starts_with("COM") && upper[3..].chars().next().is_some_and(|c| c.is_ascii_digit()))
}

impl FromStr for LinkAddress {
    type Err = UrlError;

    fn from_str(url: &str) -> Result<Self, UrlError> {
        let url = url.trim();
        if url.is_empty() {
            return Err(UrlError::Empty);
        }
        if looks_like_device(url) {
            return serial(url, url);
        }
        let Some((scheme, rest)) = url.split_once(':') else {
            return Err(UrlError::UnknownScheme { url: url.into(), scheme: url.into() });
        };
        match scheme.to_ascii_lowercase().as_str() {
            "udpin" | "udp" => Ok(Self::UdpIn(host_port(url, scheme, rest)?)),
            "udpout" => Ok(Self::UdpOut(host_port(url, scheme, rest)?)),
            "tcp" | "tcpout" => Ok(Self::TcpOut(host_port(url, scheme, rest)?)),
            "tcpin" => Ok(Self::TcpIn(host_port(url, scheme, rest)?)),
            "serial" => serial(url, rest),
            _ => Err(UrlError::UnknownScheme { url: url.into(), scheme: scheme.into() }),
        }
    }
}

/// The `mavlink` crate's form of the address (`udpin:`, `udpout:`, `tcpout:`, `tcpin:`,
/// `serial:DEVICE:BAUD`).
impl fmt::Display for LinkAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UdpIn(a) => write!(f, "udpin:{a}"),
            Self::UdpOut(a) => write!(f, "udpout:{a}"),
            Self::TcpOut(a) => write!(f, "tcpout:{a}"),
            Self::TcpIn(a) => write!(f, "tcpin:{a}"),
            Self::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<LinkAddress, UrlError> {
        s.parse()
    }

    #[test]
    fn the_forms_mavlink_tools_write_map_onto_the_crates() {
        let cases = [
            ("udpin:0.0.0.0:14550", "udpin:0.0.0.0:14550"),
            ("udp:0.0.0.0:14550", "udpin:0.0.0.0:14550"),
            ("udpout:192.168.2.2:14550", "udpout:192.168.2.2:14550"),
            ("tcp:127.0.0.1:5760", "tcpout:127.0.0.1:5760"),
            ("tcpout:localhost:5760", "tcpout:localhost:5760"),
            ("tcpin:0.0.0.0:5760", "tcpin:0.0.0.0:5760"),
            ("udpin:[::1]:14550", "udpin:[::1]:14550"),
            ("/dev/ttyACM0:115200", "serial:/dev/ttyACM0:115200"),
            ("/dev/ttyACM0,57600", "serial:/dev/ttyACM0:57600"),
            ("serial:/dev/ttyACM0:115200", "serial:/dev/ttyACM0:115200"),
            ("COM3:115200", "serial:COM3:115200"),
        ];
        for (given, crate_form) in cases {
            assert_eq!(parse(given).unwrap().to_string(), crate_form, "{given}");
        }
        assert_eq!(
            parse("/dev/ttyUSB0:921600").unwrap(),
            LinkAddress::Serial { device: "/dev/ttyUSB0".into(), baud: 921_600 }
        );
    }

    #[test]
    fn bad_addresses_say_what_is_wrong() {
        assert_eq!(parse("  "), Err(UrlError::Empty));
        assert!(matches!(parse("http:1.2.3.4:80"), Err(UrlError::UnknownScheme { scheme, .. }) if scheme == "http"));
        assert!(matches!(parse("localhost"), Err(UrlError::UnknownScheme { .. })));
        for bad in ["udpin:0.0.0.0", "udpin:0.0.0.0:port", "udpout::14550", "tcp:host:70000", "udpin:h:0"] {
            let e = parse(bad).unwrap_err();
            assert!(matches!(e, UrlError::BadHostPort { .. }), "{bad}: {e}");
            assert!(e.to_string().contains("HOST:PORT"), "{e}");
        }
        for bad in ["/dev/ttyACM0", "serial:/dev/ttyACM0", "/dev/ttyACM0:fast", "serial::115200", "COM3:0"] {
            assert!(matches!(parse(bad), Err(UrlError::BadSerial { .. })), "{bad}");
        }
    }
}
