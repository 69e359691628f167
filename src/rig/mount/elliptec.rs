//! Thorlabs Elliptec ELL14 / ELL18 rotation mounts over their documented
//! ASCII protocol: RS-232 through a USB serial adaptor, 9600 8N1, no flow
//! control, half duplex. A command is `<address><two letters>[data]`
//! (`0in`, `0ho0`, `0ma0000A000`, `0gp`, `0gs`); a reply is
//! `<address><two capitals>[data]\r\n` (`0IN…`, `0PO…`, `0GS…`). Positions
//! are signed 32-bit pulses in 8 hex digits; the pulses per revolution come
//! from the `in` reply (read, not assumed). One command at a time, each
//! waited for: users report skipped commands when they are sent back to back.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use super::{angle_between, wrap_degrees, MountError, RotationMount};

/// The line speed of every Elliptec device.
pub(crate) const BAUD: u32 = 9600;

/// How long a reply may take to a query.
pub const QUERY_TIMEOUT: Duration = Duration::from_millis(500);

/// How long a move or a homing may take (a full turn is under 2 s).
pub const MOVE_TIMEOUT: Duration = Duration::from_secs(6);

/// How far a position read back may be from the one asked for, degrees
/// (a few pulses of an ELL14's 143360 per turn).
pub(crate) const TOLERANCE_DEG: f64 = 0.05;

/// What a device says about itself (`in`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Info {
    /// Device type (14 for the ELL14).
    pub motor_type: u8,
    /// Serial number.
    pub serial: String,
    /// Year of manufacture.
    pub year: String,
    /// Firmware release.
    pub firmware: String,
    /// Travel: degrees for a rotation mount (360).
    pub travel: u32,
    /// Pulses over the travel.
    pub pulses: u32,
}

/// A reply, parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// `PO`: the position, pulses.
    Position(i32),
    /// `GS`: a status code (0 is OK).
    Status(u8),
    /// `IN`: the device's information.
    Info(Info),
}

/// The packet for `cmd` to the device at `address`, with 32-bit `data` in
/// 8 upper-case hex digits when given (a position in two's complement).
pub fn packet(address: char, cmd: &str, data: Option<i32>) -> String {
    match data {
        Some(d) => format!("{address}{cmd}{:08X}", d as u32),
        None => format!("{address}{cmd}"),
    }
}

/// What a status code means, in the protocol manual's words.
pub(crate) fn status_meaning(code: u8) -> &'static str {
    match code {
        0 => "OK",
        1 => "communication timeout",
        2 => "mechanical timeout",
        3 => "command error or not supported",
        4 => "value out of range",
        5 => "module isolated",
        6 => "module out of isolation",
        7 => "initializing error",
        8 => "thermal error",
        9 => "busy",
        10 => "sensor error",
        11 => "motor error",
        12 => "out of range",
        13 => "over current error",
        _ => "unknown status code",
    }
}

/// Why a reply line from the mount could not be read: each variant names
/// the part of the line that was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReplyError {
    /// The line has bytes outside ASCII (noise on the line, a wrong baud rate).
    #[error("not ASCII")]
    NotAscii,
    /// The line is empty.
    #[error("empty")]
    Empty,
    /// Another device on the bus answered.
    #[error("from address {from:?}, not {expected:?}")]
    Address {
        /// The address the line starts with.
        from: char,
        /// The mount's address.
        expected: char,
    },
    /// The line ends before its two-letter code.
    #[error("too short")]
    TooShort,
    /// A field has the wrong number of characters.
    #[error("{what} {data:?} is not {digits} hex digits")]
    Length {
        /// The field (`position`, `status`).
        what: &'static str,
        /// What the line held there.
        data: String,
        /// The digits the protocol gives it.
        digits: usize,
    },
    /// A field that must be hexadecimal is not.
    #[error("{what} {data:?} is not hex")]
    NotHex {
        /// The field.
        what: &'static str,
        /// What the line held there.
        data: String,
    },
    /// An information reply of the wrong length.
    #[error("information of {0} characters, not 30")]
    InfoLength(usize),
    /// An information reply with zero travel or zero pulses per unit.
    #[error("zero travel or zero pulses")]
    ZeroTravel,
    /// A reply code this driver does not know.
    #[error("unknown reply code {0:?}")]
    UnknownCode(String),
}

fn hex(s: &str, what: &'static str) -> Result<u32, ReplyError> {
    let not_hex = || ReplyError::NotHex {
        what,
        data: s.to_string(),
    };
    if s.is_empty() || !s.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(not_hex());
    }
    u32::from_str_radix(s, 16).map_err(|_| not_hex())
}

/// Parses one reply line (without its `\r\n`) from the device at `address`.
pub fn parse_reply(address: char, line: &str) -> Result<Reply, ReplyError> {
    if !line.is_ascii() {
        return Err(ReplyError::NotAscii);
    }
    let mut chars = line.chars();
    let from = chars.next().ok_or(ReplyError::Empty)?;
    if from != address {
        return Err(ReplyError::Address {
            from,
            expected: address,
        });
    }
    let (code, data) = (line.get(1..3).ok_or(ReplyError::TooShort)?, &line[3..]);
    let length = |what: &'static str, digits: usize| ReplyError::Length {
        what,
        data: data.to_string(),
        digits,
    };
    match code {
        "PO" => {
            if data.len() != 8 {
                return Err(length("position", 8));
            }
            Ok(Reply::Position(hex(data, "position")? as i32))
        }
        "GS" => {
            if data.len() != 2 {
                return Err(length("status", 2));
            }
            Ok(Reply::Status(hex(data, "status")? as u8))
        }
        "IN" => {
            // type 2, serial 8, year 4, firmware 2, thread + hardware 2, travel 4, pulses 8.
            if data.len() != 30 {
                return Err(ReplyError::InfoLength(data.len()));
            }
            let info = Info {
                motor_type: hex(&data[0..2], "motor type")? as u8,
                serial: data[2..10].to_string(),
                year: data[10..14].to_string(),
                firmware: data[14..16].to_string(),
                travel: hex(&data[18..22], "travel")?,
                pulses: hex(&data[22..30], "pulses")?,
            };
            if info.pulses == 0 || info.travel == 0 {
                return Err(ReplyError::ZeroTravel);
            }
            Ok(Reply::Info(info))
        }
        other => Err(ReplyError::UnknownCode(other.to_string())),
    }
}

/// An Elliptec rotation mount on a serial port (or anything that reads and
/// writes like one).
pub struct Elliptec<P> {
    port: P,
    path: String,
    address: char,
    info: Info,
}

impl Elliptec<Box<dyn serialport::SerialPort>> {
    /// Opens the mount at `path` (e.g. `/dev/ttyUSB0`) with device address
    /// `address` (`0` unless it was changed), and reads its information.
    pub fn open(path: &str, address: char) -> Result<Self, MountError> {
        let port = crate::rig::serial::open(path, BAUD).map_err(|e| MountError::Open {
            port: path.to_string(),
            reason: e.to_string(),
        })?;
        Self::with_port(port, path, address)
    }
}

impl<P: Read + Write + Send> Elliptec<P> {
    /// The mount on `port` (its reads time out after a short while), named
    /// `path` in errors; reads its information.
    pub fn with_port(port: P, path: &str, address: char) -> Result<Self, MountError> {
        let mut m = Self {
            port,
            path: path.to_string(),
            address,
            info: Info {
                motor_type: 0,
                serial: String::new(),
                year: String::new(),
                firmware: String::new(),
                travel: 360,
                pulses: 1,
            },
        };
        match m.transact("in", None, QUERY_TIMEOUT)? {
            Reply::Info(info) => m.info = info,
            other => return Err(m.unexpected("in", &format!("{other:?}"), "not an IN reply")),
        }
        Ok(m)
    }

    /// What the device said about itself.
    pub fn info(&self) -> &Info {
        &self.info
    }

    fn degrees(&self, pulses: i32) -> f64 {
        wrap_degrees(f64::from(pulses) * f64::from(self.info.travel) / f64::from(self.info.pulses))
    }

    fn pulses(&self, deg: f64) -> i32 {
        (wrap_degrees(deg) * f64::from(self.info.pulses) / f64::from(self.info.travel)).round()
            as i32
    }

    fn unexpected(&self, command: &str, reply: &str, why: &str) -> MountError {
        MountError::Reply {
            port: self.path.clone(),
            command: command.to_string(),
            reply: reply.to_string(),
            why: why.to_string(),
        }
    }

    /// Sends one command and waits up to `timeout` for its reply line.
    fn transact(
        &mut self,
        cmd: &str,
        data: Option<i32>,
        timeout: Duration,
    ) -> Result<Reply, MountError> {
        let packet = packet(self.address, cmd, data);
        let io = |e: std::io::Error| MountError::Io {
            port: self.path.clone(),
            command: packet.clone(),
            reason: e.to_string(),
        };
        self.port.write_all(packet.as_bytes()).map_err(io)?;
        self.port.flush().map_err(io)?;
        let deadline = Instant::now() + timeout;
        let mut line = Vec::new();
        let mut byte = [0u8; 64];
        loop {
            if let Some(end) = line.windows(2).position(|w| w == b"\r\n") {
                let text = String::from_utf8_lossy(&line[..end]).into_owned();
                return parse_reply(self.address, &text)
                    .map_err(|why| self.unexpected(&packet, &text, &why.to_string()));
            }
            if line.len() > 256 {
                let text = String::from_utf8_lossy(&line).into_owned();
                return Err(self.unexpected(&packet, &text, "no line end in 256 bytes"));
            }
            if Instant::now() >= deadline {
                return Err(MountError::NoReply {
                    port: self.path.clone(),
                    command: packet,
                    timeout_ms: timeout.as_millis() as u64,
                });
            }
            match self.port.read(&mut byte) {
                Ok(0) => std::thread::sleep(Duration::from_millis(5)),
                Ok(n) => line.extend_from_slice(&byte[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => {
                    return Err(MountError::Io {
                        port: self.path.clone(),
                        command: packet,
                        reason: e.to_string(),
                    })
                }
            }
        }
    }

    /// A position reply, or the device's error.
    fn position_reply(&self, command: &str, reply: Reply) -> Result<f64, MountError> {
        match reply {
            Reply::Position(p) => Ok(self.degrees(p)),
            Reply::Status(0) => Err(self.unexpected(command, "status OK", "no position")),
            Reply::Status(code) => Err(MountError::Device {
                port: self.path.clone(),
                command: command.to_string(),
                code,
                meaning: status_meaning(code),
            }),
            Reply::Info(_) => Err(self.unexpected(command, "IN", "not a position")),
        }
    }
}

impl<P: Read + Write + Send> RotationMount for Elliptec<P> {
    fn home(&mut self) -> Result<f64, MountError> {
        // Direction 0 (clockwise) for a rotation mount.
        let packet = format!("{}ho0", self.address);
        let r = self.transact("ho0", None, MOVE_TIMEOUT)?;
        self.position_reply(&packet, r)
    }

    fn move_to(&mut self, deg: f64) -> Result<f64, MountError> {
        let target = self.pulses(deg);
        let packet = packet(self.address, "ma", Some(target));
        let r = self.transact("ma", Some(target), MOVE_TIMEOUT)?;
        self.position_reply(&packet, r)?;
        // The position the move reports is the controller's; read it again.
        let got = self.position()?;
        let wanted = wrap_degrees(deg);
        if angle_between(got, wanted) > TOLERANCE_DEG {
            return Err(MountError::Missed {
                port: self.path.clone(),
                wanted,
                got,
                tolerance: TOLERANCE_DEG,
            });
        }
        Ok(got)
    }

    fn position(&mut self) -> Result<f64, MountError> {
        let packet = format!("{}gp", self.address);
        let r = self.transact("gp", None, QUERY_TIMEOUT)?;
        self.position_reply(&packet, r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn packets_and_replies_as_the_manual_writes_them() {
        assert_eq!(packet('0', "gp", None), "0gp");
        assert_eq!(packet('0', "ma", Some(0x4600)), "0ma00004600");
        assert_eq!(packet('A', "ma", Some(-1)), "AmaFFFFFFFF");
        assert_eq!(parse_reply('0', "0PO00004600"), Ok(Reply::Position(0x4600)));
        assert_eq!(parse_reply('0', "0POFFFFFFFF"), Ok(Reply::Position(-1)));
        assert_eq!(parse_reply('0', "0GS02"), Ok(Reply::Status(2)));
        let info = parse_reply('0', "0IN0E1140051720231701016800023000").unwrap();
        assert_eq!(
            info,
            Reply::Info(Info {
                motor_type: 14,
                serial: "11400517".into(),
                year: "2023".into(),
                firmware: "17".into(),
                travel: 360,
                pulses: 143_360,
            })
        );
        for bad in [
            "",
            "1PO00004600",
            "0PO4600",
            "0POxyz00000",
            "0GS2",
            "0XX",
            "0IN0E",
            "0PO0000460é",
        ] {
            assert!(parse_reply('0', bad).is_err(), "{bad:?}");
        }
        assert_eq!(status_meaning(2), "mechanical timeout");
    }

    proptest! {
        /// Any line, however hostile, parses or is refused; never a panic.
        #[test]
        fn any_reply_line_parses_or_is_refused(line in ".{0,64}") {
            let _ = parse_reply('0', &line);
        }

        /// A position written as a packet's data reads back as the same pulses.
        #[test]
        fn positions_round_trip(p in any::<i32>()) {
            let pkt = packet('0', "ma", Some(p));
            let reply = format!("0PO{}", &pkt[3..]);
            prop_assert_eq!(parse_reply('0', &reply), Ok(Reply::Position(p)));
        }
    }
}
