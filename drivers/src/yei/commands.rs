//! YEI 3-Space commands: the subset the driver and the simulated device use,
//! with their argument and answer sizes. Pure, like [`super::protocol`].

use super::protocol::{checksum, HeaderConfig, StreamLayout, START_NO_HEADER, START_WITH_HEADER};

/// A command the host sends to the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// 0x26: corrected gyroscope (3 x f32 rad/s).
    GetCorrectedGyro,
    /// 0x27: corrected accelerometer (3 x f32 g).
    GetCorrectedAccel,
    /// 0x28: corrected compass (3 x f32 gauss).
    GetCorrectedCompass,
    /// 0x2B: temperature (f32 degrees Celsius).
    GetTemperatureC,
    /// 0x40: all raw component data (9 x f32).
    GetRawAll,
    /// 0x41: raw gyroscope.
    GetRawGyro,
    /// 0x42: raw accelerometer.
    GetRawAccel,
    /// 0x43: raw compass.
    GetRawCompass,
    /// 0x50: streaming slots, 8 command bytes, 0xFF = empty.
    SetStreamingSlots([u8; 8]),
    /// 0x52: streaming timing, microseconds; duration 0xFFFFFFFF = forever.
    SetStreamingTiming {
        /// Time between streamed packets, microseconds.
        interval_us: u32,
        /// How long to stream, microseconds; [`STREAM_FOREVER`] for no end.
        duration_us: u32,
        /// Wait before the first packet, microseconds.
        delay_us: u32,
    },
    /// 0x55: start streaming.
    StartStreaming,
    /// 0x56: stop streaming.
    StopStreaming,
    /// 0x5F: set the sensor's microsecond clock.
    SetTimestamp(u32),
    /// 0x60: tare with the current orientation.
    Tare,
    /// 0xDD: response header bitfield.
    SetResponseHeader(HeaderConfig),
    /// 0xDF: firmware version, 12 ASCII bytes.
    GetFirmwareVersion,
    /// 0xE7: set the baud rate.
    SetBaudRate(u32),
    /// 0xE8: get the baud rate (u32).
    GetBaudRate,
    /// 0xED: serial number (u32).
    GetSerialNumber,
}

/// Duration value meaning "stream until told to stop".
pub const STREAM_FOREVER: u32 = 0xFFFF_FFFF;

impl Command {
    /// The command byte sent after the start byte.
    pub fn opcode(&self) -> u8 {
        match self {
            Command::GetCorrectedGyro => 0x26,
            Command::GetCorrectedAccel => 0x27,
            Command::GetCorrectedCompass => 0x28,
            Command::GetTemperatureC => 0x2B,
            Command::GetRawAll => 0x40,
            Command::GetRawGyro => 0x41,
            Command::GetRawAccel => 0x42,
            Command::GetRawCompass => 0x43,
            Command::SetStreamingSlots(_) => 0x50,
            Command::SetStreamingTiming { .. } => 0x52,
            Command::StartStreaming => 0x55,
            Command::StopStreaming => 0x56,
            Command::SetTimestamp(_) => 0x5F,
            Command::Tare => 0x60,
            Command::SetResponseHeader(_) => 0xDD,
            Command::GetFirmwareVersion => 0xDF,
            Command::SetBaudRate(_) => 0xE7,
            Command::GetBaudRate => 0xE8,
            Command::GetSerialNumber => 0xED,
        }
    }

    /// Argument bytes that follow `opcode`, or `None` for a command this
    /// codec does not know.
    pub fn arg_len(opcode: u8) -> Option<usize> {
        Some(match opcode {
            0x26..=0x28 | 0x2B | 0x40..=0x43 | 0x55 | 0x56 | 0x60 | 0xDF | 0xE8 | 0xED => 0,
            0x50 => 8,
            0x52 => 12,
            0x5F | 0xDD | 0xE7 => 4,
            _ => return None,
        })
    }

    /// Bytes of data the sensor answers with.
    pub fn answer_len(&self) -> usize {
        match self {
            Command::GetCorrectedGyro
            | Command::GetCorrectedAccel
            | Command::GetCorrectedCompass
            | Command::GetRawGyro
            | Command::GetRawAccel
            | Command::GetRawCompass => 12,
            Command::GetRawAll => 36,
            Command::GetTemperatureC | Command::GetBaudRate | Command::GetSerialNumber => 4,
            Command::GetFirmwareVersion => 12,
            _ => 0,
        }
    }

    fn write_args(&self, out: &mut Vec<u8>) {
        match self {
            Command::SetStreamingSlots(slots) => out.extend_from_slice(slots),
            Command::SetStreamingTiming {
                interval_us,
                duration_us,
                delay_us,
            } => {
                out.extend_from_slice(&interval_us.to_be_bytes());
                out.extend_from_slice(&duration_us.to_be_bytes());
                out.extend_from_slice(&delay_us.to_be_bytes());
            }
            Command::SetTimestamp(v) | Command::SetBaudRate(v) => {
                out.extend_from_slice(&v.to_be_bytes())
            }
            Command::SetResponseHeader(h) => out.extend_from_slice(&h.0.to_be_bytes()),
            _ => {}
        }
    }

    /// Appends `start cmd args checksum`; `with_header` picks 0xF9 over 0xF7.
    pub fn encode(&self, with_header: bool, out: &mut Vec<u8>) {
        out.push(if with_header {
            START_WITH_HEADER
        } else {
            START_NO_HEADER
        });
        let body = out.len();
        out.push(self.opcode());
        self.write_args(out);
        let sum = checksum(&out[body..]);
        out.push(sum);
    }

    /// Slots command for a layout.
    pub fn slots_for(layout: &StreamLayout) -> Command {
        Command::SetStreamingSlots(layout.slot_bytes())
    }

    /// Builds a command from its opcode and exactly [`Self::arg_len`] bytes.
    pub fn from_parts(opcode: u8, args: &[u8]) -> Option<Command> {
        let u32_arg =
            |at: usize| u32::from_be_bytes([args[at], args[at + 1], args[at + 2], args[at + 3]]);
        if args.len() != Command::arg_len(opcode)? {
            return None;
        }
        Some(match opcode {
            0x26 => Command::GetCorrectedGyro,
            0x27 => Command::GetCorrectedAccel,
            0x28 => Command::GetCorrectedCompass,
            0x2B => Command::GetTemperatureC,
            0x40 => Command::GetRawAll,
            0x41 => Command::GetRawGyro,
            0x42 => Command::GetRawAccel,
            0x43 => Command::GetRawCompass,
            0x50 => {
                let mut slots = [0u8; 8];
                slots.copy_from_slice(args);
                Command::SetStreamingSlots(slots)
            }
            0x52 => Command::SetStreamingTiming {
                interval_us: u32_arg(0),
                duration_us: u32_arg(4),
                delay_us: u32_arg(8),
            },
            0x55 => Command::StartStreaming,
            0x56 => Command::StopStreaming,
            0x5F => Command::SetTimestamp(u32_arg(0)),
            0x60 => Command::Tare,
            0xDD => Command::SetResponseHeader(HeaderConfig(u32_arg(0))),
            0xDF => Command::GetFirmwareVersion,
            0xE7 => Command::SetBaudRate(u32_arg(0)),
            0xE8 => Command::GetBaudRate,
            0xED => Command::GetSerialNumber,
            _ => return None,
        })
    }
}

/// What the device side reads off the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Received {
    /// A well-formed command; `with_header` when it started with 0xF9.
    Command {
        /// The decoded command.
        command: Command,
        /// True when the host asked for a response header (start byte 0xF9).
        with_header: bool,
    },
    /// A framed command whose checksum did not match (ignored by a device).
    BadChecksum {
        /// The command byte of the rejected command.
        opcode: u8,
    },
    /// A start byte followed by an opcode this codec does not know.
    UnknownOpcode {
        /// The unknown command byte.
        opcode: u8,
    },
}

/// Device-side parser of the host's command stream (used by the simulated
/// sensor). Bytes that are not a start byte are skipped.
#[derive(Debug, Default, Clone)]
pub struct CommandParser {
    buf: Vec<u8>,
}

impl CommandParser {
    /// Appends bytes read from the line, in any chunking.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next command, or `None` when more bytes are needed.
    pub fn next_received(&mut self) -> Option<Received> {
        let start = self
            .buf
            .iter()
            .position(|b| *b == START_NO_HEADER || *b == START_WITH_HEADER);
        let Some(start) = start else {
            self.buf.clear();
            return None;
        };
        self.buf.drain(..start);
        if self.buf.len() < 2 {
            return None;
        }
        let opcode = self.buf[1];
        let Some(arg_len) = Command::arg_len(opcode) else {
            self.buf.drain(..2);
            return Some(Received::UnknownOpcode { opcode });
        };
        let total = 2 + arg_len + 1;
        if self.buf.len() < total {
            return None;
        }
        let with_header = self.buf[0] == START_WITH_HEADER;
        let args = &self.buf[2..2 + arg_len];
        let ok = checksum(&self.buf[1..2 + arg_len]) == self.buf[total - 1];
        let received = if ok {
            let command = Command::from_parts(opcode, args)
                .expect("arg_len and from_parts agree on known opcodes");
            Received::Command {
                command,
                with_header,
            }
        } else {
            Received::BadChecksum { opcode }
        };
        self.buf.drain(..total);
        Some(received)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stop_streaming_is_f7_56_56() {
        let mut out = Vec::new();
        Command::StopStreaming.encode(false, &mut out);
        assert_eq!(out, [0xF7, 0x56, 0x56]);
    }

    #[test]
    fn timing_args_are_big_endian() {
        let mut out = Vec::new();
        Command::SetStreamingTiming {
            interval_us: 500,
            duration_us: STREAM_FOREVER,
            delay_us: 0,
        }
        .encode(true, &mut out);
        let body = [0x52, 0, 0, 0x01, 0xF4, 0xFF, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0];
        assert_eq!(out[0], 0xF9);
        assert_eq!(&out[1..14], &body);
        let sum = body.iter().map(|b| *b as u32).sum::<u32>() % 256;
        assert_eq!(out[14] as u32, sum);
    }

    #[test]
    fn parser_round_trips_every_command_through_noise() {
        let commands = [
            Command::StopStreaming,
            Command::SetResponseHeader(HeaderConfig::STREAMING),
            Command::SetStreamingSlots([0x26, 0x27, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]),
            Command::SetStreamingTiming {
                interval_us: 5000,
                duration_us: STREAM_FOREVER,
                delay_us: 10,
            },
            Command::SetTimestamp(0xDEAD_BEEF),
            Command::GetSerialNumber,
            Command::GetFirmwareVersion,
            Command::SetBaudRate(921_600),
            Command::StartStreaming,
        ];
        let mut bytes = vec![0x00, 0x13];
        for (i, c) in commands.iter().enumerate() {
            c.encode(i % 2 == 0, &mut bytes);
        }
        let mut p = CommandParser::default();
        let mut got = Vec::new();
        for b in bytes.chunks(3) {
            p.push(b);
            while let Some(r) = p.next_received() {
                got.push(r);
            }
        }
        let expected: Vec<_> = commands
            .iter()
            .enumerate()
            .map(|(i, c)| Received::Command {
                command: *c,
                with_header: i % 2 == 0,
            })
            .collect();
        assert_eq!(got, expected);
    }

    #[test]
    fn parser_reports_bad_checksum_and_unknown_opcode() {
        let mut p = CommandParser::default();
        p.push(&[0xF7, 0x56, 0x57, 0xF9, 0x01]);
        assert_eq!(
            p.next_received(),
            Some(Received::BadChecksum { opcode: 0x56 })
        );
        assert_eq!(
            p.next_received(),
            Some(Received::UnknownOpcode { opcode: 0x01 })
        );
        assert_eq!(p.next_received(), None);
    }
}
