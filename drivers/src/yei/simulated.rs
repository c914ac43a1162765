//! A simulated YEI 3-Space serving the binary protocol on the far side of a
//! pseudo-terminal, for testing the real driver without hardware.
//!
//! [`SimulatedYei::start`] opens a pty pair (`serialport::TTYPort::pair`),
//! points a stable symlink at the slave (as a udev rule would for a real
//! sensor) and serves the master from a thread: it answers the commands the
//! driver uses, streams at the interval the host configured from a generated
//! or recorded motion, with its own clock running at a configurable drift,
//! and injects [`Fault`]s on demand.

use std::io::{self, Read, Write};

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};

use super::commands::{Command, CommandParser, Received};
use super::protocol::{
    encode_response, encode_stream_packet, HeaderConfig, StreamLayout, StreamPacket, StreamValues,
    STANDARD_GRAVITY_M_S2,
};
use crate::ImuSample;

/// Where the simulated sensor's readings come from.
#[derive(Debug, Clone)]
pub enum Motion {
    /// [`generated_values`]: smooth sinusoids, a function of sensor time.
    Generated,
    /// Recorded samples (SI units), played in a loop, one per packet.
    Recorded(Arc<[ImuSample]>),
}

/// How the far end behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Behaviour {
    /// A working YEI 3-Space.
    Normal,
    /// Reads everything, answers nothing (wrong device, powered off).
    Silent,
    /// Answers every command with text (another device, or the wrong baud).
    Babble,
}

/// Settings of the simulated sensor.
#[derive(Debug, Clone)]
pub struct SimConfig {
    /// Serial number the sensor reports (command 0xED).
    pub serial: u32,
    /// 12 ASCII bytes, as command 0xDF returns.
    pub firmware: String,
    /// Sensor clock when streaming starts, u32 microseconds; the first
    /// packet is stamped one interval later (set close to 2^32 to make the
    /// stream wrap).
    pub start_timestamp_us: u32,
    /// Sensor clock rate error against the host, ppm.
    pub drift_ppm: f64,
    /// Where the streamed readings come from.
    pub motion: Motion,
    /// Whether the sensor answers at all.
    pub behaviour: Behaviour,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            serial: 0x1234_5678,
            firmware: "25Apr2013A00".into(),
            start_timestamp_us: 1_000,
            drift_ppm: 0.0,
            motion: Motion::Generated,
            behaviour: Behaviour::Normal,
        }
    }
}

/// A fault to inject into the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Write this many noise bytes between two packets.
    Garbage(usize),
    /// Lose this many bytes from the middle of the next packet.
    DropBytes(usize),
    /// Corrupt the payload checksum of the next packet.
    BadChecksum,
    /// Close the port (the sensor vanishes) and come back on a new pty
    /// behind the same symlink after the given time.
    ClosePort {
        /// How long the port stays gone.
        reopen_after: Duration,
    },
}

/// What the simulated sensor has done, for comparing with the driver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimStats {
    /// Complete, valid packets written.
    pub packets_sent: u64,
    /// Packets written damaged (dropped bytes, bad checksum).
    pub packets_damaged: u64,
    /// Noise bytes written between packets ([`Fault::Garbage`]).
    pub garbage_bytes: u64,
    /// Times the port was (re)opened.
    pub connections: u64,
    /// Commands answered.
    pub commands: u64,
}

/// The sensor values at sensor time `t_s` for [`Motion::Generated`].
pub fn generated_values(t_s: f64) -> StreamValues {
    use std::f64::consts::TAU;
    let gyro = [
        0.3 * (TAU * 0.5 * t_s).sin(),
        0.2 * (TAU * 0.3 * t_s).cos(),
        0.05 + 0.1 * (TAU * 0.2 * t_s).sin(),
    ];
    let accel_g = [
        0.02 * (TAU * 0.7 * t_s).sin(),
        -0.01,
        1.0 + 0.01 * (TAU * t_s).cos(),
    ];
    StreamValues {
        gyro_rad_s: Some(gyro.map(|x| x as f32)),
        accel_g: Some(accel_g.map(|x| x as f32)),
        compass_gauss: Some([0.2, 0.0, -0.4]),
        temperature_c: Some(31.5),
        raw_gyro: Some(gyro.map(|x| x as f32)),
        raw_accel: Some(accel_g.map(|x| x as f32)),
        raw_compass: Some([0.2, 0.0, -0.4]),
    }
}

static NEXT_ID: AtomicU64 = AtomicU64::new(0);

/// A running simulated sensor; stops and cleans up on drop.
pub struct SimulatedYei {
    link: PathBuf,
    dir: PathBuf,
    faults: Sender<Fault>,
    stats: Arc<Mutex<SimStats>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

struct Pty {
    master: TTYPort,
    // Held open so that the master never sees a hang-up between driver
    // connections.
    _slave: TTYPort,
}

fn open_pty(link: &Path) -> io::Result<Pty> {
    let (mut master, slave) = TTYPort::pair().map_err(io::Error::from)?;
    master
        .set_timeout(Duration::from_millis(1))
        .map_err(io::Error::from)?;
    let name = slave
        .name()
        .ok_or_else(|| io::Error::other("pty slave without a name"))?;
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(name, &tmp)?;
    std::fs::rename(&tmp, link)?;
    Ok(Pty {
        master,
        _slave: slave,
    })
}

impl SimulatedYei {
    /// Creates a pty pair and a symlink to its slave in a fresh directory
    /// under the system temp dir, and starts serving; errors when the pty,
    /// the link or the thread cannot be created.
    pub fn start(config: SimConfig) -> io::Result<SimulatedYei> {
        let dir = std::env::temp_dir().join(format!(
            "rigslam-yei-sim-{}-{}",
            std::process::id(),
            NEXT_ID.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir)?;
        let link = dir.join("tty");
        let pty = open_pty(&link)?;
        let (faults, fault_rx) = mpsc::channel();
        let stats = Arc::new(Mutex::new(SimStats {
            connections: 1,
            ..Default::default()
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let mut server = Server::new(config, link.clone(), fault_rx, stats.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("yei-sim".into())
            .spawn(move || server.run(pty))?;
        Ok(SimulatedYei {
            link,
            dir,
            faults,
            stats,
            stop,
            thread: Some(thread),
        })
    }

    /// The path the driver opens (a symlink to the current pty slave).
    pub fn path(&self) -> &Path {
        &self.link
    }

    /// Queues a fault; it takes effect at the next streamed packet
    /// ([`Fault::ClosePort`] at once).
    pub fn inject(&self, fault: Fault) {
        // The server only goes away on drop, which needs &mut self.
        let _ = self.faults.send(fault);
    }

    /// What the sensor has done so far.
    pub fn stats(&self) -> SimStats {
        *self.stats.lock().expect("sim stats lock is never poisoned")
    }
}

impl Drop for SimulatedYei {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

struct Server {
    config: SimConfig,
    link: PathBuf,
    faults: Receiver<Fault>,
    stats: Arc<Mutex<SimStats>>,
    stop: Arc<AtomicBool>,
    header: HeaderConfig,
    layout: StreamLayout,
    interval_us: u32,
    /// Host instant of sensor-clock zero for the stream and packet index.
    streaming: Option<(Instant, u64)>,
    pending: Vec<Fault>,
    noise: u64,
    out: Vec<u8>,
}

impl Server {
    fn new(
        config: SimConfig,
        link: PathBuf,
        faults: Receiver<Fault>,
        stats: Arc<Mutex<SimStats>>,
        stop: Arc<AtomicBool>,
    ) -> Server {
        Server {
            config,
            link,
            faults,
            stats,
            stop,
            header: HeaderConfig(0),
            layout: StreamLayout::gyro_accel(),
            interval_us: 10_000,
            streaming: None,
            pending: Vec::new(),
            noise: 0x9E37_79B9_7F4A_7C15,
            out: Vec::with_capacity(4096),
        }
    }

    fn stat(&self, f: impl FnOnce(&mut SimStats)) {
        f(&mut self.stats.lock().expect("sim stats lock is never poisoned"));
    }

    fn run(&mut self, mut pty: Pty) {
        let mut parser = CommandParser::default();
        let mut buf = [0u8; 1024];
        while !self.stop.load(Ordering::Relaxed) {
            self.pending.extend(self.faults.try_iter());
            if let Some(pos) = self
                .pending
                .iter()
                .position(|f| matches!(f, Fault::ClosePort { .. }))
            {
                let Fault::ClosePort { reopen_after } = self.pending.remove(pos) else {
                    unreachable!("position matched ClosePort")
                };
                drop(pty);
                let _ = std::fs::remove_file(&self.link);
                self.streaming = None;
                self.header = HeaderConfig(0);
                parser = CommandParser::default();
                let until = Instant::now() + reopen_after;
                while Instant::now() < until && !self.stop.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(2));
                }
                match open_pty(&self.link) {
                    Ok(p) => pty = p,
                    Err(_) => return,
                }
                self.stat(|s| s.connections += 1);
                continue;
            }
            match pty.master.read(&mut buf) {
                Ok(n) if n > 0 => {
                    parser.push(&buf[..n]);
                    while let Some(r) = parser.next_received() {
                        self.answer(r);
                    }
                }
                _ => {}
            }
            self.stream_due();
            // Block while the host does not read, as a USB CDC sensor does
            // (no silent loss on this side: lost packets are the host's).
            let mut written = 0;
            while written < self.out.len() && !self.stop.load(Ordering::Relaxed) {
                match pty.master.write(&self.out[written..]) {
                    Ok(n) => written += n,
                    Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(_) => break,
                }
            }
            self.out.clear();
        }
    }

    fn sensor_clock_us(&self, since: Duration) -> u64 {
        (since.as_secs_f64() * 1e6 * (1.0 + self.config.drift_ppm * 1e-6)) as u64
    }

    fn answer(&mut self, received: Received) {
        let Received::Command {
            command,
            with_header,
        } = received
        else {
            return;
        };
        match self.config.behaviour {
            Behaviour::Normal => {}
            Behaviour::Silent => return,
            Behaviour::Babble => {
                self.out.extend_from_slice(b"ERROR: unknown command\r\n");
                return;
            }
        }
        self.stat(|s| s.commands += 1);
        let mut data = Vec::new();
        match command {
            Command::StopStreaming => self.streaming = None,
            Command::StartStreaming => {}
            Command::SetResponseHeader(h) => self.header = h,
            Command::SetStreamingSlots(slots) => {
                if let Ok(layout) = StreamLayout::from_slot_bytes(slots) {
                    self.layout = layout;
                }
            }
            Command::SetStreamingTiming { interval_us, .. } => {
                self.interval_us = interval_us.max(1)
            }
            Command::GetSerialNumber => data.extend_from_slice(&self.config.serial.to_be_bytes()),
            Command::GetFirmwareVersion => {
                let mut fw = [b' '; 12];
                for (d, s) in fw.iter_mut().zip(self.config.firmware.bytes()) {
                    *d = s;
                }
                data.extend_from_slice(&fw);
            }
            Command::GetBaudRate => data.extend_from_slice(&115_200u32.to_be_bytes()),
            Command::GetTemperatureC => data.extend_from_slice(&31.5f32.to_be_bytes()),
            c if c.answer_len() > 0 => {
                let layout =
                    StreamLayout::new(&[super::protocol::StreamSlot::from_opcode(c.opcode())
                        .expect("read commands with answers are stream slots")])
                    .expect("one slot is a valid layout");
                layout.encode_payload(&generated_values(0.0), &mut data);
            }
            _ => {}
        }
        if with_header {
            encode_response(
                self.header,
                command.opcode(),
                self.config.start_timestamp_us,
                &data,
                &mut self.out,
            );
        } else {
            self.out.extend_from_slice(&data);
        }
        if command == Command::StartStreaming {
            self.streaming = Some((Instant::now(), 0));
        }
    }

    fn values(&self, k: u64, t_s: f64) -> StreamValues {
        match &self.config.motion {
            Motion::Generated => generated_values(t_s),
            Motion::Recorded(samples) if !samples.is_empty() => {
                let s = samples[(k % samples.len() as u64) as usize];
                StreamValues {
                    gyro_rad_s: Some(s.gyro_rad_s.map(|x| x as f32)),
                    accel_g: Some(s.accel_m_s2.map(|x| (x / STANDARD_GRAVITY_M_S2) as f32)),
                    ..generated_values(t_s)
                }
            }
            Motion::Recorded(_) => generated_values(t_s),
        }
    }

    fn noise_byte(&mut self) -> u8 {
        // xorshift64: reproducible noise without a dependency.
        self.noise ^= self.noise << 13;
        self.noise ^= self.noise >> 7;
        self.noise ^= self.noise << 17;
        (self.noise >> 24) as u8
    }

    /// Writes every packet whose time has come.
    fn stream_due(&mut self) {
        let Some((t0, mut k)) = self.streaming else {
            return;
        };
        let now_us = self.sensor_clock_us(t0.elapsed());
        while (k + 1) * self.interval_us as u64 <= now_us {
            k += 1;
            let sensor_us = k * self.interval_us as u64;
            let packet = StreamPacket {
                timestamp_us: self
                    .config
                    .start_timestamp_us
                    .wrapping_add(sensor_us as u32),
                values: self.values(k, sensor_us as f64 * 1e-6),
            };
            let from = self.out.len();
            encode_stream_packet(self.header, &self.layout, &packet, &mut self.out);
            let mut damaged = false;
            let faults = std::mem::take(&mut self.pending);
            for fault in faults {
                match fault {
                    Fault::Garbage(n) => {
                        let noise: Vec<u8> = (0..n).map(|_| self.noise_byte()).collect();
                        self.out.splice(from..from, noise);
                        self.stat(|s| s.garbage_bytes += n as u64);
                    }
                    Fault::DropBytes(n) => {
                        let start = from + self.header.len() + 2;
                        let end = (start + n).min(self.out.len());
                        self.out.drain(start..end);
                        damaged = true;
                    }
                    Fault::BadChecksum => {
                        // Flip a payload bit: the checksum no longer matches.
                        let at = self.out.len() - 1;
                        self.out[at] ^= 0x01;
                        damaged = true;
                    }
                    other => self.pending.push(other),
                }
            }
            self.stat(|s| {
                if damaged {
                    s.packets_damaged += 1
                } else {
                    s.packets_sent += 1
                }
            });
        }
        self.streaming = Some((t0, k));
    }
}
