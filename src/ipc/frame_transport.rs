//! Zero-copy frame transport: the camera side's [`FramePublisher`] and the
//! tracker side's [`FrameSubscriber`].
//!
//! The publisher loans a sample in shared memory, lets the camera source
//! write header and pixels in place, validates the header, sends, and raises
//! the frame event. The subscriber blocks on that event (with a deadline to
//! notice a silent camera), takes the newest frame,
//! validates it, and hands the tracker a view into shared memory. Neither side
//! allocates per frame. Counters say what was published, dropped and rejected.

use std::ops::ControlFlow;
use std::time::Duration;

use iceoryx2::identifiers::UniquePublisherId;
use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::sample::Sample;
use iceoryx2::service::ipc;
use tracing::{debug, info, warn};

use super::frame::{Frame, FrameError, FrameSlot, FrameView};
use super::services::{open_event_service, open_frame_service, FRAME_EVENT_SERVICE, FRAME_SERVICE};
use super::IpcError;

/// Camera-side counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublisherStats {
    /// Frames sent.
    pub published: u64,
    /// Frames whose header failed validation and were not sent.
    pub rejected: u64,
    /// Frames the source failed to produce (the loan was returned unsent).
    pub source_errors: u64,
}

/// Why [`FramePublisher::publish_with`] did not publish.
#[derive(Debug, thiserror::Error)]
pub enum PublishError<E> {
    /// The source failed to fill the frame.
    #[error("camera source: {0}")]
    Source(E),
    /// The source filled an inconsistent header; the frame was dropped.
    #[error("frame rejected: {0}")]
    Rejected(FrameError),
    /// iceoryx2 failed (loan, send or notify).
    #[error(transparent)]
    Ipc(IpcError),
}

/// Publishes frames built in place in shared memory.
pub struct FramePublisher {
    publisher: Publisher<ipc::Service, Frame, ()>,
    notifier: Notifier<ipc::Service>,
    sequence: u64,
    stats: PublisherStats,
}

impl FramePublisher {
    /// Opens the frame and event services on `node` and creates the ports.
    pub fn new(node: &Node<ipc::Service>) -> Result<Self, IpcError> {
        let service = open_frame_service(node)?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(1)
            .create()
            .map_err(|e| IpcError::iceoryx("create publisher", FRAME_SERVICE, e))?;
        let event = open_event_service(node, FRAME_EVENT_SERVICE)?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("create notifier", FRAME_EVENT_SERVICE, e))?;
        Ok(Self {
            publisher,
            notifier,
            sequence: 0,
            stats: PublisherStats::default(),
        })
    }

    /// Loans a frame, lets `fill` write its header and pixels in place, then
    /// validates and sends it and wakes the subscribers. The publisher sets
    /// `header.sequence`. Returns the sequence number sent.
    pub fn publish_with<E>(
        &mut self,
        fill: impl FnOnce(&mut FrameSlot<'_>) -> Result<(), E>,
    ) -> Result<u64, PublishError<E>> {
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| PublishError::Ipc(IpcError::iceoryx("loan", FRAME_SERVICE, e)))?;
        {
            // SAFETY: the sample lives in iceoryx2's mmap'd data segment; see
            // `FrameSlot::from_uninit`.
            let mut slot = unsafe { FrameSlot::from_uninit(sample.payload_mut()) };
            if let Err(e) = fill(&mut slot) {
                self.stats.source_errors += 1;
                return Err(PublishError::Source(e));
            }
            slot.header.sequence = self.sequence;
            if let Err(e) = slot.header.validate() {
                self.stats.rejected += 1;
                return Err(PublishError::Rejected(e));
            }
        }
        // SAFETY: as above, every byte of the sample is an initialized byte
        // and every bit pattern is a valid `Frame`.
        let sample = unsafe { sample.assume_init() };
        sample
            .send()
            .map_err(|e| PublishError::Ipc(IpcError::iceoryx("send", FRAME_SERVICE, e)))?;
        self.notifier
            .notify()
            .map_err(|e| PublishError::Ipc(IpcError::iceoryx("notify", FRAME_EVENT_SERVICE, e)))?;
        let sent = self.sequence;
        self.sequence += 1;
        self.stats.published += 1;
        Ok(sent)
    }

    /// Counters so far.
    pub fn stats(&self) -> PublisherStats {
        self.stats
    }
}

/// Tracker-side counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubscriberStats {
    /// Valid frames handed to the consumer.
    pub received: u64,
    /// Frames the camera published that this consumer never saw (it was
    /// slower, and the newest frame replaced them).
    pub dropped: u64,
    /// Frames with an inconsistent header, discarded.
    pub rejected: u64,
    /// Times frames started coming from a new publisher (camera restart).
    pub publisher_changes: u64,
    /// Deadlines that passed with no frame (camera silent).
    pub silent_periods: u64,
}

/// A frame received in shared memory, validated. Holding it keeps the
/// sample borrowed; drop it before taking the next one.
pub struct ReceivedFrame {
    sample: Sample<ipc::Service, Frame, ()>,
}

impl ReceivedFrame {
    /// The frame, read in place. The header is validated again here, since
    /// another process wrote it.
    pub fn view(&self) -> Result<FrameView<'_>, FrameError> {
        self.sample.payload().view()
    }
}

/// What the consumer's callback in [`FrameSubscriber::run`] is given.
pub enum FrameEvent<'a> {
    /// The newest frame.
    Frame(FrameView<'a>),
    /// No frame arrived within the deadline.
    Silent,
}

/// How [`FrameSubscriber::run`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    /// The callback asked to stop.
    Stopped,
    /// SIGINT or SIGTERM arrived.
    TerminationRequested,
}

struct Ports {
    subscriber: Subscriber<ipc::Service, Frame, ()>,
    listener: Listener<ipc::Service>,
}

#[derive(Default)]
struct ReceiveState {
    last: Option<(UniquePublisherId, u64)>,
    stats: SubscriberStats,
}

/// Receives frames zero-copy, newest first, counting drops and rejects.
pub struct FrameSubscriber {
    ports: Ports,
    state: ReceiveState,
}

impl FrameSubscriber {
    /// Opens the frame and event services on `node` and creates the ports.
    pub fn new(node: &Node<ipc::Service>) -> Result<Self, IpcError> {
        let service = open_frame_service(node)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(1)
            .create()
            .map_err(|e| IpcError::iceoryx("create subscriber", FRAME_SERVICE, e))?;
        let event = open_event_service(node, FRAME_EVENT_SERVICE)?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("create listener", FRAME_EVENT_SERVICE, e))?;
        Ok(Self {
            ports: Ports {
                subscriber,
                listener,
            },
            state: ReceiveState::default(),
        })
    }

    /// The frame event listener, to attach to a WaitSet of the caller's own.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.ports.listener
    }

    /// Counters so far.
    pub fn stats(&self) -> SubscriberStats {
        self.state.stats
    }

    /// Non-blocking: consumes pending notifications and returns the newest
    /// valid frame, if any. Older frames still buffered are released and
    /// counted as dropped; invalid ones are counted as rejected.
    pub fn take_latest(&mut self) -> Result<Option<ReceivedFrame>, IpcError> {
        self.state.take_latest(&self.ports)
    }

    /// Blocks on the frame event until frames arrive and calls `on_event`
    /// with the newest one; when nothing arrives for `silence`, calls it with
    /// [`FrameEvent::Silent`]. Returns when `on_event` breaks or on
    /// SIGINT/SIGTERM.
    ///
    /// This waits on the event listener directly rather than through a
    /// [`WaitSet`](iceoryx2::prelude::WaitSet): iceoryx2 0.10's WaitSet
    /// allocates a vector on every wake-up, which would break the tracker's
    /// allocation-free steady state. The listener is the same primitive the
    /// WaitSet multiplexes; callers that need to wait on more than frames can
    /// attach [`FrameSubscriber::listener`] to their own WaitSet and call
    /// [`FrameSubscriber::take_latest`].
    pub fn run(
        &mut self,
        silence: Duration,
        mut on_event: impl FnMut(FrameEvent<'_>) -> ControlFlow<()>,
    ) -> Result<RunEnd, IpcError> {
        let mut silent = false;
        loop {
            if termination_requested() {
                return Ok(RunEnd::TerminationRequested);
            }
            let flow = match self.state.take_latest(&self.ports)? {
                Some(frame) => match frame.view() {
                    Ok(view) => {
                        if silent {
                            info!("camera frames resumed");
                            silent = false;
                        }
                        on_event(FrameEvent::Frame(view))
                    }
                    Err(e) => {
                        self.state.stats.rejected += 1;
                        warn!(error = %e, "rejected frame");
                        ControlFlow::Continue(())
                    }
                },
                None => {
                    let woken = self
                        .ports
                        .listener
                        .timed_wait(|_| {}, silence)
                        .map_err(|e| IpcError::iceoryx("wait", FRAME_EVENT_SERVICE, e))?;
                    if woken > 0 || self.ports.subscriber.has_samples().unwrap_or(false) {
                        continue;
                    }
                    self.state.stats.silent_periods += 1;
                    if !silent {
                        warn!(silence_ms = silence.as_millis() as u64, "no camera frames");
                        silent = true;
                    }
                    on_event(FrameEvent::Silent)
                }
            };
            if flow.is_break() {
                return Ok(RunEnd::Stopped);
            }
        }
    }
}

/// Whether SIGINT or SIGTERM arrived (iceoryx2's signal handler records them).
fn termination_requested() -> bool {
    iceoryx2_bb_posix::signal::SignalHandler::termination_requested()
}

impl ReceiveState {
    fn take_latest(&mut self, ports: &Ports) -> Result<Option<ReceivedFrame>, IpcError> {
        ports
            .listener
            .try_wait(|_| {})
            .map_err(|e| IpcError::iceoryx("wait", FRAME_EVENT_SERVICE, e))?;
        let mut newest: Option<ReceivedFrame> = None;
        loop {
            let sample = ports
                .subscriber
                .receive()
                .map_err(|e| IpcError::iceoryx("receive", FRAME_SERVICE, e))?;
            let Some(sample) = sample else { break };
            let header = sample.payload().header;
            if let Err(e) = header.validate() {
                self.stats.rejected += 1;
                warn!(error = %e, rejected = self.stats.rejected, "rejected frame");
                continue;
            }
            self.account(sample.origin(), header.sequence);
            if newest.is_some() {
                // A buffered older frame is released unseen.
                self.stats.dropped += 1;
            }
            newest = Some(ReceivedFrame { sample });
        }
        if newest.is_some() {
            self.stats.received += 1;
        }
        Ok(newest)
    }

    fn account(&mut self, origin: UniquePublisherId, sequence: u64) {
        match self.last {
            Some((last_origin, last_seq)) if last_origin == origin && sequence > last_seq => {
                self.stats.dropped += sequence - last_seq - 1;
            }
            Some((last_origin, _)) if last_origin == origin => {
                debug!(sequence, "frame sequence did not increase");
            }
            Some(_) => {
                self.stats.publisher_changes += 1;
                info!(sequence, "frames resumed from a new camera publisher");
            }
            None => info!(sequence, "first frame from camera"),
        }
        self.last = Some((origin, sequence));
    }
}
