//! The consumer's side: block on the stream's event service until a sample
//! is there (no polling), then take the samples, or only the newest.

use std::time::{Duration, Instant};

use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;

use super::access::Access;
use super::message::{PoseMessage, StatusMessage};
use super::service::{create_node, Ipc, IpcConfig, IpcError, Message, Services, Stream};

/// How often a subscription narrows the files it created meanwhile.
const NARROWING_PERIOD: Duration = Duration::from_secs(1);

/// Samples a subscriber queues unless told otherwise.
pub const DEFAULT_SUBSCRIBER_BUFFER: usize = 16;

/// A subscription to one stream. `Send`: it may live on any thread.
pub struct Subscription<T: Message> {
    service: String,
    subscriber: Subscriber<Ipc, T, ()>,
    listener: Listener<Ipc>,
    check: SampleCheck,
    access: Access,
    next_narrowing: Instant,
    membership_warned: bool,
    _services: Services<T>,
    // Dropped last: the ports above belong to it.
    _node: Node<Ipc>,
}

/// Subscribes to `<prefix>/pose` or `<prefix>/pose_fast`.
pub type PoseSubscriber = Subscription<PoseMessage>;
/// Subscribes to `<prefix>/status`.
pub type StatusSubscriber = Subscription<StatusMessage>;

impl PoseSubscriber {
    /// Subscribes to `<prefix>/pose` with the default buffer.
    pub fn pose(config: &IpcConfig) -> Result<Self, IpcError> {
        Self::open_service(
            config,
            &Stream::Pose.service_name(&config.service_prefix),
            DEFAULT_SUBSCRIBER_BUFFER,
        )
    }

    /// Subscribes to `<prefix>/pose_fast` with the default buffer.
    pub fn pose_fast(config: &IpcConfig) -> Result<Self, IpcError> {
        Self::open_service(
            config,
            &Stream::PoseFast.service_name(&config.service_prefix),
            DEFAULT_SUBSCRIBER_BUFFER,
        )
    }
}

impl StatusSubscriber {
    /// Subscribes to `<prefix>/status`.
    pub fn status(config: &IpcConfig) -> Result<Self, IpcError> {
        Self::open_service(
            config,
            &Stream::Status.service_name(&config.service_prefix),
            DEFAULT_SUBSCRIBER_BUFFER,
        )
    }
}

/// What a subscriber checks of every sample it takes, whatever bytes the
/// publisher put in shared memory: the layout version, and the sequence
/// number against the previous sample's (a gap counts as missed samples).
#[derive(Debug, Clone, Default)]
pub struct SampleCheck {
    last_sequence: Option<u64>,
    missed: u64,
}

impl SampleCheck {
    /// Checks `message`, taken from `service` (named in the error).
    pub fn accept<T: Message>(&mut self, service: &str, message: &T) -> Result<(), IpcError> {
        if message.layout_version() != T::LAYOUT_VERSION {
            return Err(IpcError::LayoutVersion {
                service: service.to_string(),
                found: message.layout_version(),
                expected: T::LAYOUT_VERSION,
            });
        }
        // The publisher writes the sequence; it may be anything (a
        // restart, u64::MAX), so no step here may overflow.
        if let Some(last) = self.last_sequence {
            if let Some(gap) = message
                .sequence()
                .checked_sub(last)
                .and_then(|d| d.checked_sub(1))
            {
                self.missed = self.missed.saturating_add(gap);
            }
        }
        self.last_sequence = Some(message.sequence());
        Ok(())
    }

    /// Samples skipped between the ones accepted (sequence gaps).
    pub fn missed(&self) -> u64 {
        self.missed
    }
}

impl<T: Message> Subscription<T> {
    /// Subscribes to the service with the full name `service` (e.g.
    /// `rigslam/pose`). When the daemon runs as another user, the service
    /// must exist ([`IpcError::NotPublished`] otherwise) and this user must
    /// be in its group ([`IpcError::Permission`] names the group and how
    /// to join it); as the daemon's own user it is created if no
    /// publisher has yet. `buffer` is how many samples wait for
    /// [`Self::take_all`]; when more arrive the oldest are dropped (1
    /// keeps only the newest).
    pub fn open_service(
        config: &IpcConfig,
        service: &str,
        buffer: usize,
    ) -> Result<Self, IpcError> {
        let access = Access::for_subscriber(config)?;
        let node = create_node(config)?;
        let services =
            Services::<T>::open(config, &node, service, access.services_of_another_user())?;
        let (subscriber, listener) = services.subscriber(buffer)?;
        // This process's files (node, event socket and counter, connection
        // segments) to the daemon's group, away from everyone else.
        access.narrow_own_files()?;
        Ok(Self {
            service: service.to_string(),
            subscriber,
            listener,
            check: SampleCheck::default(),
            access,
            next_narrowing: Instant::now() + NARROWING_PERIOD,
            membership_warned: false,
            _services: services,
            _node: node,
        })
    }

    /// Blocks on the event service until a sample is waiting or `timeout`
    /// has passed; true when a sample is waiting. Returns at once when
    /// samples are already there. Wake-ups without a sample (events of a
    /// previous sample already taken) go back to waiting.
    pub fn wait(&mut self, timeout: Duration) -> Result<bool, IpcError> {
        let deadline = Instant::now() + timeout;
        if Instant::now() >= self.next_narrowing {
            // Connection segments to a publisher that came later.
            self.next_narrowing = Instant::now() + NARROWING_PERIOD;
            if let Err(e) = self.access.narrow_own_files() {
                tracing::warn!("{}: {e}", self.service);
            }
            if !self.membership_warned {
                if let Some(warning) = self.access.membership_lost() {
                    tracing::warn!("{}: {warning}", self.service);
                    self.membership_warned = true;
                }
            }
        }
        loop {
            if self
                .subscriber
                .has_samples()
                .map_err(|e| IpcError::service(&self.service, "check for samples", e))?
            {
                // Consume the notifications that announced them, so that a
                // later wait does not return for samples already taken.
                self.listener
                    .try_wait(|_| {})
                    .map_err(|e| IpcError::service(&self.service, "read events", e))?;
                return Ok(true);
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(false);
            }
            self.listener
                .timed_wait(|_| {}, deadline - now)
                .map_err(|e| IpcError::service(&self.service, "wait for event", e))?;
        }
    }

    /// Takes one waiting sample, `None` when there is none.
    pub fn take(&mut self) -> Result<Option<T>, IpcError> {
        let sample = self
            .subscriber
            .receive()
            .map_err(|e| IpcError::service(&self.service, "receive sample", e))?;
        let Some(sample) = sample else {
            return Ok(None);
        };
        let message: T = *sample.payload();
        drop(sample);
        self.check.accept(&self.service, &message)?;
        Ok(Some(message))
    }

    /// Takes every waiting sample, oldest first, appending to `out`;
    /// returns how many.
    pub fn take_all(&mut self, out: &mut Vec<T>) -> Result<usize, IpcError> {
        let before = out.len();
        while let Some(message) = self.take()? {
            out.push(message);
        }
        Ok(out.len() - before)
    }

    /// Takes every waiting sample and returns the newest (what a
    /// controller wants when it lags).
    pub fn take_newest(&mut self) -> Result<Option<T>, IpcError> {
        let mut newest = None;
        while let Some(message) = self.take()? {
            newest = Some(message);
        }
        Ok(newest)
    }

    /// [`Self::wait`] then [`Self::take_newest`].
    pub fn wait_newest(&mut self, timeout: Duration) -> Result<Option<T>, IpcError> {
        if self.wait(timeout)? {
            self.take_newest()
        } else {
            Ok(None)
        }
    }

    /// Samples skipped between the ones taken (sequence gaps): samples
    /// dropped because the buffer overflowed, or before this subscriber
    /// connected after the first taken one.
    pub fn missed(&self) -> u64 {
        self.check.missed()
    }

    /// The full service name.
    pub fn service_name(&self) -> &str {
        &self.service
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(sequence: u64) -> PoseMessage {
        let mut m = PoseMessage::new(
            0,
            crate::relative::types::TrackingState::Tracking,
            &nalgebra::Isometry3::identity(),
        );
        m.sequence = sequence;
        m
    }

    #[test]
    fn gaps_count_as_missed_and_restarts_do_not() {
        let mut check = SampleCheck::default();
        for s in [0, 1, 5, 6, 2, 3] {
            check
                .accept("rigslam/pose", &pose(s))
                .expect("current layout");
        }
        assert_eq!(check.missed(), 3);
    }

    /// Found by fuzzing: a sample with sequence u64::MAX made the next
    /// one overflow `last + 1` (a panic with overflow checks, a wrapped
    /// count without), and huge gaps could overflow the count.
    #[test]
    fn any_sequence_a_publisher_writes_is_taken() {
        let mut check = SampleCheck::default();
        for s in [u64::MAX, 0, u64::MAX, 0, 5] {
            check
                .accept("rigslam/pose", &pose(s))
                .expect("current layout");
        }
        assert_eq!(check.missed(), u64::MAX);
    }

    #[test]
    fn a_foreign_layout_is_refused_by_name() {
        let mut m = pose(0);
        m.layout_version = 99;
        let e = SampleCheck::default()
            .accept("rigslam/pose", &m)
            .unwrap_err()
            .to_string();
        assert!(e.contains("rigslam/pose") && e.contains("99"), "{e}");
    }
}
