//! YEI 3-Space device driver: owns the serial port and a decode thread.
//!
//! [`YeiDevice::open`] opens the port, stops any stream left running, reads
//! the serial number and firmware, configures the response header, the
//! streaming slots and timing, starts the stream and hands the port to a
//! thread that decodes packets ([`StreamDecoder`]), unwraps the 32-bit
//! microsecond clock, counts lost packets from timestamp gaps, maps sensor
//! time onto host `CLOCK_MONOTONIC` ([`ClockSync`]) and queues
//! [`YeiSample`]s. When the port vanishes (unplugged, closed) the thread
//! reopens it with exponential backoff and redoes the handshake.

use std::io::{self, Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use thiserror::Error;

use super::commands::{Command, STREAM_FOREVER};
use super::protocol::{
    find_response, HeaderConfig, ProtocolError, ResponseScan, StreamDecoder, StreamLayout,
    StreamPacket, StreamValues, STANDARD_GRAVITY_M_S2,
};
use crate::clock_sync::{ClockSync, ClockSyncConfig};
use crate::ImuSample;

/// How to reach and configure the sensor.
#[derive(Debug, Clone)]
pub struct YeiConfig {
    /// Serial device, e.g. `/dev/ttyACM0` or a udev symlink.
    pub port: String,
    /// Line speed; the YEI factory default is 115200.
    pub baud: u32,
    /// Streaming interval, microseconds (5000 = 200 Hz).
    pub interval_us: u32,
    /// Streaming slots; the default is corrected gyro + corrected accel.
    pub layout: StreamLayout,
    /// How long to wait for each handshake answer.
    pub response_timeout: Duration,
    /// First wait before reopening a vanished port; doubles up to
    /// `reconnect_max`.
    pub reconnect_initial: Duration,
    /// Longest wait between reopen attempts.
    pub reconnect_max: Duration,
    /// Samples buffered for the consumer before new ones are dropped (and
    /// counted as `queue_overflows`).
    pub queue_capacity: usize,
}

impl YeiConfig {
    /// Defaults for a sensor on `port`: 115200 baud, 200 Hz of corrected
    /// gyro + accel, 500 ms per handshake answer, reconnect waits from
    /// 50 ms up to 2 s, 65536 queued samples.
    pub fn new(port: impl Into<String>) -> YeiConfig {
        YeiConfig {
            port: port.into(),
            baud: 115_200,
            interval_us: 5_000,
            layout: StreamLayout::gyro_accel(),
            response_timeout: Duration::from_millis(500),
            reconnect_initial: Duration::from_millis(50),
            reconnect_max: Duration::from_secs(2),
            queue_capacity: 1 << 16,
        }
    }
}

impl YeiConfig {
    /// Samples per second the configured interval asks for.
    pub fn rate_hz(&self) -> f64 {
        1e6 / f64::from(self.interval_us.max(1))
    }

    /// Line speed the configured stream needs: every packet is the
    /// streaming header plus the slots' payload, at 10 bits per byte (8N1).
    pub fn needed_baud(&self) -> f64 {
        let packet_bytes = HeaderConfig::STREAMING.len() + self.layout.payload_len();
        (packet_bytes * 10) as f64 * self.rate_hz()
    }

    /// Refuses a stream the line cannot carry, before anything is sent: a
    /// UART at too low a speed would drop most packets and look like a
    /// broken sensor. (Over USB the baud is nominal, but the sensor still
    /// paces its output by it, so the same rule holds.)
    pub fn check_line_budget(&self) -> Result<(), YeiError> {
        if self.interval_us == 0 {
            return Err(YeiError::BadConfig {
                port: self.port.clone(),
                why: "streaming interval is 0 us; give a rate between 1 Hz and 10 kHz".into(),
            });
        }
        let needed = self.needed_baud();
        if needed > f64::from(self.baud) * LINE_BUDGET {
            return Err(YeiError::BadConfig {
                port: self.port.clone(),
                why: format!(
                    "{:.0} Hz of {} bytes per packet needs {needed:.0} baud, more than {:.0} % of the configured {} baud; raise the baud rate (the sensor accepts up to 921600) or lower the rate",
                    self.rate_hz(),
                    HeaderConfig::STREAMING.len() + self.layout.payload_len(),
                    LINE_BUDGET * 100.0,
                    self.baud
                ),
            });
        }
        Ok(())
    }
}

/// Share of the line speed a stream may use: leaves room for the
/// occasional command answer and for clock tolerance between the ends.
const LINE_BUDGET: f64 = 0.9;

/// Who the sensor says it is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct YeiIdentity {
    /// Serial number (command 0xED).
    pub serial: u32,
    /// Firmware version string (command 0xDF), trailing NULs and spaces
    /// trimmed.
    pub firmware: String,
}

impl YeiIdentity {
    /// The serial number as printed on the sensor's label (8 hex digits).
    pub fn serial_hex(&self) -> String {
        format!("{:08X}", self.serial)
    }
}

/// One decoded sample with its stamps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YeiSample {
    /// Gyro and accel in SI units, stamped on the host monotonic clock.
    pub imu: ImuSample,
    /// Sensor clock, microseconds, unwrapped past 2^32.
    pub sensor_t_us: u64,
    /// Host `CLOCK_MONOTONIC` when the bytes were read, ns.
    pub receipt_t_ns: i64,
    /// Everything the configured slots carried.
    pub values: StreamValues,
}

/// Counters of the decode thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct YeiStats {
    /// Samples decoded and queued.
    pub samples: u64,
    /// Framed packets rejected as corrupt (payload checksum).
    pub checksum_errors: u64,
    /// Times the decoder lost and regained packet sync.
    pub resyncs: u64,
    /// Bytes skipped while resynchronising.
    pub skipped_bytes: u64,
    /// Packets missing, from gaps in the sensor timestamps.
    pub drops: u64,
    /// 32-bit microsecond clock wraps seen.
    pub wraps: u64,
    /// Sensor clock jumps (backwards or > 1 s forwards) that restarted the
    /// clock alignment.
    pub clock_jumps: u64,
    /// Packets dropped because their timestamp left the timeline (a
    /// corrupt header; the header is not checksummed).
    pub timestamp_rejects: u64,
    /// Times the port vanished.
    pub disconnects: u64,
    /// Successful reopen + handshake after a disconnect.
    pub reconnects: u64,
    /// Samples dropped because the consumer did not keep up.
    pub queue_overflows: u64,
}

/// What went wrong talking to the sensor, with what was tried and what to
/// check.
#[derive(Debug, Error)]
pub enum YeiError {
    /// The serial port could not be opened.
    #[error("cannot open serial port {port} at {baud} baud: {source}; check the path (ls /dev/ttyACM* /dev/ttyUSB* /dev/serial/by-id), that you may open it (dialout group) and that no other program holds it")]
    Open {
        /// Serial device path.
        port: String,
        /// Line speed tried.
        baud: u32,
        /// The serial library's error.
        source: serialport::Error,
    },
    /// Reading or writing the port failed during the handshake.
    #[error("I/O error on {port} while {doing}: {source}")]
    Io {
        /// Serial device path.
        port: String,
        /// The handshake step ("sending a command").
        doing: &'static str,
        /// The OS error.
        source: io::Error,
    },
    /// Not one byte came back to a handshake command.
    #[error("{port} at {baud} baud answered nothing to {command} within {waited_ms} ms; check that a YEI 3-Space is connected to this port and powered, and that it is set to {baud} baud (the factory default is 115200)")]
    NoAnswer {
        /// Serial device path.
        port: String,
        /// Line speed used.
        baud: u32,
        /// The command, named with its opcode ("get-serial-number (0xED)").
        command: &'static str,
        /// How long we waited, milliseconds.
        waited_ms: u128,
    },
    /// Bytes came back, but no valid response to the command among them
    /// (often a wrong baud rate or another device).
    #[error("{port} at {baud} baud answered {command} with {received} bytes that are not a YEI 3-Space response (first bytes: {first_bytes}); check the baud rate (tried {baud}; the factory default is 115200) and that the device on this port is a YEI 3-Space")]
    UnexpectedAnswer {
        /// Serial device path.
        port: String,
        /// Line speed used.
        baud: u32,
        /// The command, named with its opcode.
        command: &'static str,
        /// Bytes received that were not a valid response.
        received: usize,
        /// Up to 16 of them in hex, for the user.
        first_bytes: String,
    },
    /// The configuration cannot work (zero interval, more data than the
    /// line speed carries); nothing was sent.
    #[error("{port}: {why}")]
    BadConfig {
        /// Serial device path.
        port: String,
        /// What is wrong and what to change.
        why: String,
    },
    /// The stream layout or response header is invalid.
    #[error("streaming configuration: {0}")]
    Protocol(#[from] ProtocolError),
    /// The decode thread could not be spawned.
    #[error("cannot start the decode thread: {0}")]
    Thread(io::Error),
}

/// Host `CLOCK_MONOTONIC`, nanoseconds.
pub fn host_monotonic_ns() -> i64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through a valid pointer;
    // CLOCK_MONOTONIC exists on every Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    debug_assert_eq!(rc, 0);
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// Unwraps the YEI's u32 microsecond counter.
///
/// The response header is not covered by the checksum, so a lost or
/// corrupt header byte can yield a valid-looking packet with a wrong
/// timestamp. A timestamp off the timeline is therefore held as suspect and
/// only accepted as a clock jump when the next one continues from it.
#[derive(Debug, Clone, Default)]
pub struct TimestampUnwrapper {
    last: Option<(u32, u64)>,
    suspect: Option<u32>,
}

/// What one timestamp did to the unwrapped clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockStep {
    /// The first timestamp: it anchors the unwrapped clock.
    First,
    /// On the timeline, at most `max_forward_us` after the last timestamp.
    Forward {
        /// The 32-bit counter wrapped past 2^32 on this step.
        wrapped: bool,
    },
    /// Backwards or more than `max_forward_us` ahead, confirmed by the
    /// next timestamp: a restarted clock.
    Jump,
    /// Off the timeline and not (yet) confirmed: the sample is dropped.
    Suspect,
}

impl TimestampUnwrapper {
    /// Unwrapped microseconds; a forward step of at most `max_forward_us`
    /// across 2^32 counts as a wrap, anything else as a jump that re-anchors.
    pub fn unwrap(&mut self, t_us: u32, max_forward_us: u64) -> (u64, ClockStep) {
        let Some((last, last_full)) = self.last else {
            self.last = Some((t_us, t_us as u64));
            return (t_us as u64, ClockStep::First);
        };
        let forward = t_us.wrapping_sub(last) as u64;
        if forward <= max_forward_us {
            self.suspect = None;
            let full = last_full + forward;
            self.last = Some((t_us, full));
            (
                full,
                ClockStep::Forward {
                    wrapped: t_us < last,
                },
            )
        } else if self
            .suspect
            .is_some_and(|s| (t_us.wrapping_sub(s) as u64) <= max_forward_us)
        {
            // Two timestamps agree on a new timeline: the clock jumped.
            // Keep the unwrapped clock increasing across the jump.
            let full = last_full + 1;
            self.last = Some((t_us, full));
            self.suspect = None;
            (full, ClockStep::Jump)
        } else {
            self.suspect = Some(t_us);
            (last_full, ClockStep::Suspect)
        }
    }
}

fn hex_prefix(bytes: &[u8]) -> String {
    let shown: Vec<String> = bytes.iter().take(16).map(|b| format!("{b:02X}")).collect();
    let more = if bytes.len() > 16 { " ..." } else { "" };
    format!("{}{more}", shown.join(" "))
}

/// The stream handshake over any byte port (a serial line, a pty, a test
/// double). Returns the identity and bytes already read past the start
/// acknowledgement (the first streamed packets).
pub fn handshake<P: Read + Write + ?Sized>(
    port: &mut P,
    config: &YeiConfig,
) -> Result<(YeiIdentity, Vec<u8>), YeiError> {
    let header = HeaderConfig::STREAMING;
    let io_err = |doing: &'static str| {
        let port = config.port.clone();
        move |source| YeiError::Io {
            port,
            doing,
            source,
        }
    };
    let mut out = Vec::new();
    let send = |port: &mut P, cmd: Command, with_header: bool, out: &mut Vec<u8>| {
        out.clear();
        cmd.encode(with_header, out);
        port.write_all(out).and_then(|_| port.flush())
    };
    // A sensor left streaming keeps talking: stop it, then let the line go
    // quiet (bounded, in case the far end babbles forever).
    send(port, Command::StopStreaming, false, &mut out)
        .map_err(io_err("sending stop-streaming"))?;
    let quiet_deadline = Instant::now() + config.response_timeout;
    let mut scratch = [0u8; 4096];
    let mut babble = Vec::new();
    loop {
        match port.read(&mut scratch) {
            Ok(0) => break,
            Ok(n) => {
                if babble.len() < 64 {
                    babble.extend_from_slice(&scratch[..n.min(64)]);
                }
                if Instant::now() > quiet_deadline {
                    break;
                }
            }
            Err(e) if e.kind() == io::ErrorKind::TimedOut => break,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io_err("draining the line after stop-streaming")(e)),
        }
    }
    send(port, Command::SetResponseHeader(header), false, &mut out)
        .map_err(io_err("setting the response header"))?;

    let mut ask = |port: &mut P,
                   cmd: Command,
                   name: &'static str,
                   babble: &[u8]|
     -> Result<(Vec<u8>, Vec<u8>), YeiError> {
        send(port, cmd, true, &mut out).map_err(io_err("sending a command"))?;
        let started = Instant::now();
        let mut buf: Vec<u8> = Vec::new();
        let mut received = 0usize;
        let mut seen = babble.to_vec();
        loop {
            if let ResponseScan::Found { payload_start, .. } =
                find_response(header, cmd.opcode(), cmd.answer_len(), &buf)
            {
                let end = payload_start + cmd.answer_len();
                return Ok((buf[payload_start..end].to_vec(), buf[end..].to_vec()));
            }
            if started.elapsed() > config.response_timeout {
                return Err(if received == 0 && seen.is_empty() {
                    YeiError::NoAnswer {
                        port: config.port.clone(),
                        baud: config.baud,
                        command: name,
                        waited_ms: config.response_timeout.as_millis(),
                    }
                } else {
                    seen.extend_from_slice(&buf);
                    YeiError::UnexpectedAnswer {
                        port: config.port.clone(),
                        baud: config.baud,
                        command: name,
                        received: received + babble.len(),
                        first_bytes: hex_prefix(&seen),
                    }
                });
            }
            match port.read(&mut scratch) {
                Ok(0) => {}
                Ok(n) => {
                    received += n;
                    buf.extend_from_slice(&scratch[..n]);
                }
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(io_err("waiting for an answer")(e)),
            }
        }
    };

    let (serial, _) = ask(
        port,
        Command::GetSerialNumber,
        "get-serial-number (0xED)",
        &babble,
    )?;
    let serial = u32::from_be_bytes([serial[0], serial[1], serial[2], serial[3]]);
    let (firmware, _) = ask(
        port,
        Command::GetFirmwareVersion,
        "get-firmware-version (0xDF)",
        &[],
    )?;
    let firmware = String::from_utf8_lossy(&firmware)
        .trim_end_matches(['\0', ' '])
        .to_string();
    ask(
        port,
        Command::slots_for(&config.layout),
        "set-streaming-slots (0x50)",
        &[],
    )?;
    ask(
        port,
        Command::SetStreamingTiming {
            interval_us: config.interval_us,
            duration_us: STREAM_FOREVER,
            delay_us: 0,
        },
        "set-streaming-timing (0x52)",
        &[],
    )?;
    let (_, leftover) = ask(port, Command::StartStreaming, "start-streaming (0x55)", &[])?;
    Ok((YeiIdentity { serial, firmware }, leftover))
}

type Port = Box<dyn serialport::SerialPort>;

fn open_port(config: &YeiConfig) -> Result<Port, YeiError> {
    serialport::new(&config.port, config.baud)
        .timeout(Duration::from_millis(20))
        .open()
        .map_err(|source| YeiError::Open {
            port: config.port.clone(),
            baud: config.baud,
            source,
        })
}

fn connect(config: &YeiConfig) -> Result<(Port, YeiIdentity, Vec<u8>), YeiError> {
    let mut port = open_port(config)?;
    let (identity, leftover) = handshake(&mut *port, config)?;
    Ok((port, identity, leftover))
}

struct Shared {
    stop: AtomicBool,
    stats: Mutex<YeiStats>,
}

/// A streaming YEI 3-Space.
pub struct YeiDevice {
    identity: YeiIdentity,
    samples: Receiver<YeiSample>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl YeiDevice {
    /// Opens the port, runs the handshake and starts the decode thread.
    pub fn open(config: YeiConfig) -> Result<YeiDevice, YeiError> {
        config.check_line_budget()?;
        let (port, identity, leftover) = connect(&config)?;
        let (tx, rx) = mpsc::sync_channel(config.queue_capacity);
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            stats: Mutex::new(YeiStats::default()),
        });
        let worker = Worker::new(config, tx, shared.clone())?;
        let thread = std::thread::Builder::new()
            .name("yei-decode".into())
            .spawn(move || worker.run(port, leftover))
            .map_err(YeiError::Thread)?;
        Ok(YeiDevice {
            identity,
            samples: rx,
            shared,
            thread: Some(thread),
        })
    }

    /// Serial number and firmware read during the handshake.
    pub fn identity(&self) -> &YeiIdentity {
        &self.identity
    }

    /// The next sample, waiting at most `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<YeiSample> {
        // Timeout or a finished thread: nothing to return either way.
        self.samples.recv_timeout(timeout).ok()
    }

    /// A sample if one is queued.
    pub fn try_recv(&self) -> Option<YeiSample> {
        self.samples.try_recv().ok()
    }

    /// The decode thread's counters, as of its last update.
    pub fn stats(&self) -> YeiStats {
        *self
            .shared
            .stats
            .lock()
            .expect("stats lock is never poisoned")
    }

    /// Stops the stream and the thread; returns the final counters.
    pub fn close(mut self) -> YeiStats {
        self.shutdown();
        self.stats()
    }

    fn shutdown(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for YeiDevice {
    fn drop(&mut self) {
        self.shutdown();
    }
}

struct Worker {
    config: YeiConfig,
    tx: SyncSender<YeiSample>,
    shared: Arc<Shared>,
    decoder: StreamDecoder,
    unwrapper: TimestampUnwrapper,
    clock: ClockSync,
    last_sensor_us: Option<u64>,
    /// Sensor and host stamp of the last sample, to keep stamps increasing.
    last_t_ns: Option<(i64, i64)>,
    stats: YeiStats,
}

impl Worker {
    fn new(
        config: YeiConfig,
        tx: SyncSender<YeiSample>,
        shared: Arc<Shared>,
    ) -> Result<Worker, YeiError> {
        let decoder = StreamDecoder::new(HeaderConfig::STREAMING, config.layout.clone())?;
        // A packet's time on the wire (10 bits a byte) is the floor of the
        // transport delay; the envelope fit cannot see it.
        let wire_ns = decoder.frame_len() as i64 * 10 * 1_000_000_000 / config.baud.max(1) as i64;
        let clock = ClockSync::new(ClockSyncConfig {
            min_latency_ns: wire_ns,
            ..Default::default()
        });
        Ok(Worker {
            config,
            tx,
            shared,
            decoder,
            unwrapper: TimestampUnwrapper::default(),
            clock,
            last_sensor_us: None,
            last_t_ns: None,
            stats: YeiStats::default(),
        })
    }

    fn stopping(&self) -> bool {
        self.shared.stop.load(Ordering::Relaxed)
    }

    fn publish_stats(&mut self) {
        let c = self.decoder.counts();
        let mut s = self
            .shared
            .stats
            .lock()
            .expect("stats lock is never poisoned");
        *s = YeiStats {
            checksum_errors: self.stats.checksum_errors + c.checksum_errors,
            resyncs: self.stats.resyncs + c.resyncs,
            skipped_bytes: self.stats.skipped_bytes + c.skipped_bytes,
            ..self.stats
        };
    }

    /// Folds the decoder's counts into the totals before replacing it.
    fn restart_stream_state(&mut self) {
        let c = self.decoder.counts();
        self.stats.checksum_errors += c.checksum_errors;
        self.stats.resyncs += c.resyncs;
        self.stats.skipped_bytes += c.skipped_bytes;
        self.decoder = StreamDecoder::new(HeaderConfig::STREAMING, self.config.layout.clone())
            .expect("the same configuration was accepted at start");
        self.unwrapper = TimestampUnwrapper::default();
        self.last_sensor_us = None;
        self.last_t_ns = None;
        self.clock.reset();
    }

    fn run(mut self, mut port: Port, leftover: Vec<u8>) {
        let receipt = host_monotonic_ns();
        self.decoder.push(&leftover);
        self.drain(receipt);
        let mut chunk = vec![0u8; 16 * 1024];
        let idle_limit =
            Duration::from_micros(self.config.interval_us as u64 * 50).max(Duration::from_secs(1));
        let mut last_data = Instant::now();
        while !self.stopping() {
            let lost = match port.read(&mut chunk) {
                Ok(0) => true,
                Ok(n) => {
                    let receipt = host_monotonic_ns();
                    last_data = Instant::now();
                    self.decoder.push(&chunk[..n]);
                    self.drain(receipt);
                    self.publish_stats();
                    false
                }
                Err(e) if e.kind() == io::ErrorKind::TimedOut => last_data.elapsed() > idle_limit,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => false,
                Err(_) => true,
            };
            if lost {
                self.stats.disconnects += 1;
                self.publish_stats();
                drop(port);
                match self.reconnect() {
                    Some(p) => {
                        port = p;
                        last_data = Instant::now();
                    }
                    None => return,
                }
            }
        }
        let mut out = Vec::new();
        Command::StopStreaming.encode(false, &mut out);
        let _ = port.write_all(&out);
        self.publish_stats();
    }

    /// Reopens the port with exponential backoff; `None` when asked to stop.
    fn reconnect(&mut self) -> Option<Port> {
        let mut wait = self.config.reconnect_initial;
        loop {
            let until = Instant::now() + wait;
            while Instant::now() < until {
                if self.stopping() {
                    return None;
                }
                std::thread::sleep(Duration::from_millis(5).min(wait));
            }
            if let Ok((port, _identity, leftover)) = connect(&self.config) {
                self.restart_stream_state();
                self.stats.reconnects += 1;
                self.decoder.push(&leftover);
                self.drain(host_monotonic_ns());
                self.publish_stats();
                return Some(port);
            }
            wait = (wait * 2).min(self.config.reconnect_max);
        }
    }

    fn drain(&mut self, receipt_ns: i64) {
        while let Some(packet) = self.decoder.next_packet() {
            self.handle(packet, receipt_ns);
        }
    }

    fn handle(&mut self, packet: StreamPacket, receipt_ns: i64) {
        let interval_us = self.config.interval_us.max(1) as u64;
        let (sensor_us, step) = self
            .unwrapper
            .unwrap(packet.timestamp_us, (1_000_000).max(interval_us * 100));
        match step {
            ClockStep::First => {}
            ClockStep::Forward { wrapped } => {
                if wrapped {
                    self.stats.wraps += 1;
                }
                if let Some(last) = self.last_sensor_us {
                    let gap = sensor_us - last;
                    // Round to whole intervals: sensor timing jitters a little.
                    let periods = (gap + interval_us / 2) / interval_us;
                    self.stats.drops += periods.saturating_sub(1);
                }
            }
            ClockStep::Jump => {
                self.stats.clock_jumps += 1;
                self.clock.reset();
                self.last_t_ns = None;
            }
            ClockStep::Suspect => {
                self.stats.timestamp_rejects += 1;
                return;
            }
        }
        self.last_sensor_us = Some(sensor_us);
        let sensor_ns = sensor_us as i64 * 1000;
        self.clock.observe(sensor_ns, receipt_ns);
        let mapped_ns = self.clock.to_host_ns(sensor_ns).unwrap_or(receipt_ns);
        // Refits move the mapping by microseconds (early on, by up to the
        // delay jitter); stamps must still increase, by half the sensor
        // interval where possible, so a refit never reorders or bunches
        // samples, and never lie after the receipt. The one exception:
        // several packets decoded from one read share a receipt, and before
        // the fit has settled they may all be clamped to it; strict order
        // then wins, so the k-th of them lies at most k ns after it.
        let t_ns = match self.last_t_ns {
            Some((last_sensor_ns, last_t_ns)) => mapped_ns
                .max(last_t_ns + ((sensor_ns - last_sensor_ns) / 2).max(1))
                .min(receipt_ns)
                .max(last_t_ns + 1),
            None => mapped_ns.min(receipt_ns),
        };
        self.last_t_ns = Some((sensor_ns, t_ns));
        let v = packet.values;
        let gyro = v.gyro_rad_s.unwrap_or([0.0; 3]);
        let accel = v.accel_g.unwrap_or([0.0; 3]);
        let sample = YeiSample {
            imu: ImuSample {
                t_ns,
                gyro_rad_s: gyro.map(f64::from),
                accel_m_s2: accel.map(|a| a as f64 * STANDARD_GRAVITY_M_S2),
            },
            sensor_t_us: sensor_us,
            receipt_t_ns: receipt_ns,
            values: v,
        };
        match self.tx.try_send(sample) {
            Ok(()) => self.stats.samples += 1,
            Err(TrySendError::Full(_)) => self.stats.queue_overflows += 1,
            // Nobody listens any more; keep decoding until told to stop.
            Err(TrySendError::Disconnected(_)) => self.stats.samples += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unwrapper_crosses_2_pow_32() {
        let mut u = TimestampUnwrapper::default();
        assert_eq!(
            u.unwrap(u32::MAX - 999, 1_000_000),
            (u32::MAX as u64 - 999, ClockStep::First)
        );
        let (t, step) = u.unwrap(500, 1_000_000);
        assert_eq!(t, u32::MAX as u64 + 501);
        assert_eq!(step, ClockStep::Forward { wrapped: true });
        let (t2, step) = u.unwrap(1500, 1_000_000);
        assert_eq!(
            (t2 - t, step),
            (1000, ClockStep::Forward { wrapped: false })
        );
        // One timestamp off the timeline (a corrupt header) is held back...
        assert_eq!(u.unwrap(0x00AB_0000, 1_000_000).1, ClockStep::Suspect);
        // ...and forgotten when the next one continues the old timeline.
        let (t3, step) = u.unwrap(2500, 1_000_000);
        assert_eq!(
            (t3 - t2, step),
            (1000, ClockStep::Forward { wrapped: false })
        );
        // A clock set back (command 0x5F) is a jump once confirmed, never a
        // 71-minute gap.
        assert_eq!(u.unwrap(10, 1_000_000).1, ClockStep::Suspect);
        let (t4, step) = u.unwrap(1010, 1_000_000);
        assert_eq!(step, ClockStep::Jump);
        assert!(t4 > t3);
    }

    #[test]
    fn wrong_port_names_the_path_and_what_to_check() {
        let err = YeiDevice::open(YeiConfig::new("/dev/does-not-exist-yei"))
            .err()
            .expect("no such device");
        let msg = err.to_string();
        assert!(msg.contains("/dev/does-not-exist-yei"), "{msg}");
        assert!(msg.contains("115200 baud"), "{msg}");
        assert!(msg.contains("dialout"), "{msg}");
    }
}
