//! Zero-copy frame transport: the camera side's [`FramePublisher`] and the
//! tracker side's [`FrameSubscriber`].
//!
//! The publisher loans a sample in shared memory, lets the camera source
//! write header and pixels in place, validates the header, sends, and raises
//! the frame event. The subscriber blocks on that event (with a deadline to
//! notice a silent camera), takes the newest frame,
//! validates it, and hands the tracker a view into shared memory. Neither side
//! allocates per frame. Counters say what was published, dropped and rejected.
//!
//! Waking a blocked thread costs most of the transport's latency (about
//! 30 µs of the 33 µs median on the 2-vCPU development VM, against 2.5 µs
//! when the receiver polls). A camera is periodic, so the subscriber can
//! learn the frame period and the delay from capture to arrival from the
//! frames' own stamps, block until shortly before the next frame is due, and
//! poll the queue for a short window around that time ([`ArrivalPredictor`],
//! `ipc.spin_us`, off by default). Frames that come outside the window still
//! wake it through the event.

use std::ops::ControlFlow;
use std::path::Path;
use std::time::Duration;

use iceoryx2::identifiers::UniquePublisherId;
use iceoryx2::node::Node;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{CallbackProgression, PortFactory};
use iceoryx2::sample::Sample;
use iceoryx2::service::ipc;
use iceoryx2_bb_posix::file_descriptor::FileDescriptorBased;
use tracing::{debug, info, warn};

use super::frame::{Frame, FrameError, FrameSlot, FrameView};
use super::services::{
    check_shm_space, frame_segment_bytes, open_event_service, open_existing_event_service,
    open_existing_frame_service, open_frame_service, publisher_refused, FRAME_EVENT_SERVICE,
    FRAME_MAX_LOANED, FRAME_SERVICE, SHM_DIR,
};
use super::IpcError;
use crate::clock::monotonic_now_ns;

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
        check_shm_space(Path::new(SHM_DIR), FRAME_SERVICE, frame_segment_bytes())?;
        let service = open_frame_service(node)?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(FRAME_MAX_LOANED)
            .create()
            .map_err(|e| {
                let mut holders = Vec::new();
                service.dynamic_config().list_publishers(|p| {
                    holders.push(p.node_id);
                    CallbackProgression::Continue
                });
                publisher_refused(node, FRAME_SERVICE, &holders, e)
            })?;
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
    /// Frames found by polling around their predicted arrival (the rest
    /// were pending when the consumer looked, or woke it through the event).
    pub polled: u64,
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

impl Ports {
    /// A subscriber on `service` and a listener on the frame event, and the
    /// listener's socket.
    fn open(
        service: &iceoryx2::service::port_factory::publish_subscribe::PortFactory<
            ipc::Service,
            Frame,
            (),
        >,
        event: &iceoryx2::service::port_factory::event::PortFactory<ipc::Service>,
    ) -> Result<(Self, libc::c_int), IpcError> {
        let subscriber = service
            .subscriber_builder()
            .buffer_size(1)
            .create()
            .map_err(|e| IpcError::iceoryx("create subscriber", FRAME_SERVICE, e))?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("create listener", FRAME_EVENT_SERVICE, e))?;
        // SAFETY: the descriptor is only used while `listener` (which owns
        // it) is alive: both live in the `FrameSubscriber`, and the
        // descriptor is replaced whenever the listener is.
        let listener_fd = unsafe { listener.file_descriptor().native_handle() };
        Ok((
            Self {
                subscriber,
                listener,
            },
            listener_fd,
        ))
    }
}

#[derive(Default)]
struct ReceiveState {
    last: Option<(UniquePublisherId, u64)>,
    stats: SubscriberStats,
    predictor: ArrivalPredictor,
    /// The consumer waited for the frames now pending (their arrival time
    /// is known to within the wake-up).
    awaited: bool,
}

/// Predicts when the next frame of a periodic camera arrives, from the
/// capture stamps and sequence numbers in the frame headers and from the
/// arrivals the subscriber saw while waiting. Plain arithmetic on a few
/// integers; no allocation.
///
/// A camera's clock sets a fixed schedule and every frame is late against
/// it by a varying amount (exposure readout, driver, the camera process's
/// own wake-up). So the predictor follows the schedule, not the last frame:
/// the *anchor* is the earliest capture stamp seen, projected forward by
/// the period, and it only creeps later (1/16 of the gap per frame) so that
/// a slightly wrong period cannot drag it away. The next frame is expected
/// at anchor + period + the delay from capture stamp to arrival.
#[derive(Debug, Clone, Copy, Default)]
pub struct ArrivalPredictor {
    /// The schedule's phase: a capture time on it and that frame's sequence.
    anchor: Option<(u64, u64)>,
    /// The last frame's capture stamp and sequence.
    last: Option<(u64, u64)>,
    /// Smoothed frame period, ns (0: not known yet).
    period_ns: u64,
    /// Period samples averaged so far (the smoothing starts as a plain mean).
    period_samples: u32,
    /// Smoothed delay from capture stamp to arrival, ns.
    delay_ns: Option<u64>,
}

impl ArrivalPredictor {
    /// Shortest and longest period the predictor believes in (10 kHz, 1 Hz).
    const MIN_PERIOD_NS: u64 = 100_000;
    const MAX_PERIOD_NS: u64 = 1_000_000_000;
    /// Largest believable delay from capture to arrival.
    const MAX_DELAY_NS: u64 = 1_000_000_000;
    /// Exponential smoothing weight of a new period sample, as a shift (1/16).
    const SMOOTHING_SHIFT: u32 = 4;

    /// Forgets everything (a new publisher: another camera, another clock).
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// A frame was taken: its capture stamp and sequence number.
    pub fn on_frame(&mut self, capture_ns: u64, sequence: u64) {
        let Some((last_capture, last_sequence)) = self.last else {
            self.last = Some((capture_ns, sequence));
            self.anchor = Some((capture_ns, sequence));
            return;
        };
        if sequence <= last_sequence || capture_ns <= last_capture {
            // The stream restarted or jumped back: start over.
            self.reset();
            self.on_frame(capture_ns, sequence);
            return;
        }
        let sample = (capture_ns - last_capture) / (sequence - last_sequence);
        if (Self::MIN_PERIOD_NS..=Self::MAX_PERIOD_NS).contains(&sample) {
            self.period_ns = if self.period_samples < (1 << Self::SMOOTHING_SHIFT) {
                let n = u64::from(self.period_samples);
                (self.period_ns * n + sample) / (n + 1)
            } else {
                self.period_ns - (self.period_ns >> Self::SMOOTHING_SHIFT)
                    + (sample >> Self::SMOOTHING_SHIFT)
            };
            self.period_samples = self.period_samples.saturating_add(1);
        }
        self.last = Some((capture_ns, sequence));
        let projected = match self.anchor {
            Some((anchor, anchor_sequence)) if self.period_ns > 0 => {
                anchor.saturating_add(self.period_ns.saturating_mul(sequence - anchor_sequence))
            }
            _ => capture_ns,
        };
        let phase = if capture_ns <= projected {
            capture_ns
        } else {
            projected + ((capture_ns - projected) >> Self::SMOOTHING_SHIFT)
        };
        self.anchor = Some((phase, sequence));
    }

    /// A frame that was waited for arrived at `now_ns` (so its arrival time
    /// is known, not just that it was there when the consumer looked).
    pub fn on_awaited_arrival(&mut self, capture_ns: u64, now_ns: u64) {
        let Some(delay) = now_ns.checked_sub(capture_ns) else {
            return;
        };
        if delay > Self::MAX_DELAY_NS {
            return;
        }
        self.delay_ns = Some(match self.delay_ns {
            // Toward a lower delay fast (a late wake-up only ever adds
            // delay), toward a higher one slowly.
            Some(d) if delay < d => d - ((d - delay) >> 1),
            Some(d) => d + ((delay - d) >> Self::SMOOTHING_SHIFT),
            None => delay,
        });
    }

    /// When the next frame should arrive on CLOCK_MONOTONIC, ns; `None`
    /// until a period and a delay are known.
    pub fn next_arrival_ns(&self) -> Option<u64> {
        let (anchor, _) = self.anchor?;
        let delay = self.delay_ns?;
        (self.period_samples >= 2).then(|| anchor + self.period_ns + delay)
    }

    /// The smoothed frame period, ns (0 until known).
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }
}

/// Receives frames zero-copy, newest first, counting drops and rejects.
pub struct FrameSubscriber {
    ports: Ports,
    state: ReceiveState,
    /// Half-width of the polling window around a frame's predicted arrival
    /// (0: always block on the event).
    spin: Duration,
    /// The listener's socket, to wait on with a precise timeout.
    listener_fd: libc::c_int,
}

impl FrameSubscriber {
    /// Opens the frame and event services on `node` and creates the ports.
    pub fn new(node: &Node<ipc::Service>) -> Result<Self, IpcError> {
        let service = open_frame_service(node)?;
        let event = open_event_service(node, FRAME_EVENT_SERVICE)?;
        let (ports, listener_fd) = Ports::open(&service, &event)?;
        Ok(Self {
            ports,
            state: ReceiveState::default(),
            spin: Duration::ZERO,
            listener_fd,
        })
    }

    /// Checks that this subscriber is still attached to the frame service a
    /// new camera would open. When the service's shared memory was deleted
    /// (files removed from `/dev/shm`), the next camera recreates it
    /// ([`super::services::remove_orphaned`]) and this subscriber, left on
    /// the old one, re-attaches to the new one: new ports, counters kept.
    /// Returns whether it re-attached. Opens a service, so it allocates:
    /// call it while the camera is silent, not per frame.
    pub fn reattach_if_orphaned(&mut self, node: &Node<ipc::Service>) -> Result<bool, IpcError> {
        // Open only, never create: this node still holds the old ports, and
        // iceoryx2 aborts when a node registers a service twice. The next
        // camera recreates the services; until then there is nothing to
        // attach to.
        let Some(service) = open_existing_frame_service(node)? else {
            return Ok(false);
        };
        let mine = self.ports.subscriber.id();
        let mut attached = false;
        service.dynamic_config().list_subscribers(|d| {
            attached = d.subscriber_id == mine;
            if attached {
                CallbackProgression::Stop
            } else {
                CallbackProgression::Continue
            }
        });
        if attached {
            return Ok(false);
        }
        let Some(event) = open_existing_event_service(node, FRAME_EVENT_SERVICE)? else {
            return Ok(false);
        };
        warn!(
            service = FRAME_SERVICE,
            "the frame service was recreated (its shared memory had been deleted); re-attaching"
        );
        let (ports, listener_fd) = Ports::open(&service, &event)?;
        self.ports = ports;
        self.listener_fd = listener_fd;
        self.state.predictor.reset();
        Ok(true)
    }

    /// Polls for frames during `spin` either side of a frame's predicted
    /// arrival instead of sleeping on the event (`ipc.spin_us`; zero turns
    /// polling off). At 50 Hz a 250 µs window costs at most 2.5 % of one core.
    pub fn with_spin(mut self, spin: Duration) -> Self {
        self.spin = spin;
        self
    }

    /// The arrival predictor's state (period and delay), for diagnostics.
    pub fn predictor(&self) -> &ArrivalPredictor {
        &self.state.predictor
    }

    /// Waits until frames may be ready or `timeout` passes: polls the queue
    /// around the predicted arrival (see [`FrameSubscriber::with_spin`]) and
    /// blocks on the frame event otherwise. Returns whether frames are
    /// pending; follow with [`FrameSubscriber::take_latest`].
    pub fn wait_for_frame(&mut self, timeout: Duration) -> Result<bool, IpcError> {
        let start_ns = monotonic_now_ns();
        let deadline_ns = start_ns.saturating_add(timeout.as_nanos() as u64);
        let spin_ns = self.spin.as_nanos() as u64;
        if spin_ns > 0 {
            if let Some(expected_ns) = self.state.predictor.next_arrival_ns() {
                let spin_from_ns = expected_ns.saturating_sub(spin_ns);
                let spin_until_ns = expected_ns.saturating_add(spin_ns).min(deadline_ns);
                if start_ns < spin_from_ns
                    && spin_from_ns < deadline_ns
                    && self.block(Duration::from_nanos(spin_from_ns - start_ns))?
                {
                    return Ok(true);
                }
                while monotonic_now_ns() < spin_until_ns {
                    if self.has_samples() {
                        self.state.awaited = true;
                        self.state.stats.polled += 1;
                        return Ok(true);
                    }
                    std::hint::spin_loop();
                }
            }
        }
        let now_ns = monotonic_now_ns();
        if now_ns >= deadline_ns {
            return Ok(self.has_samples());
        }
        self.block(Duration::from_nanos(deadline_ns - now_ns))
    }

    /// Blocks on the frame event for at most `timeout`.
    ///
    /// Polls the listener's socket with `ppoll` (a high-resolution timer)
    /// and then drains it, as an iceoryx2 WaitSet does: the listener's own
    /// `timed_wait` sleeps through a socket receive timeout, which the
    /// kernel rounds up to whole scheduler ticks (8 ms measured for a 0.9 ms
    /// wait), too coarse to wake up just before a frame.
    fn block(&mut self, timeout: Duration) -> Result<bool, IpcError> {
        let mut pollfd = libc::pollfd {
            fd: self.listener_fd,
            events: libc::POLLIN,
            revents: 0,
        };
        let timeout = libc::timespec {
            tv_sec: timeout.as_secs() as libc::time_t,
            tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32),
        };
        // SAFETY: `pollfd` and `timeout` are valid for the call; the fd is
        // the listener's, open for as long as `self.ports.listener` lives.
        let rc = unsafe { libc::ppoll(&mut pollfd, 1, &timeout, std::ptr::null()) };
        if rc < 0 {
            let err = std::io::Error::last_os_error();
            // A signal (SIGTERM) interrupts the wait; the caller checks for it.
            if err.kind() != std::io::ErrorKind::Interrupted {
                return Err(IpcError::iceoryx("poll", FRAME_EVENT_SERVICE, err));
            }
        }
        let woken = self
            .ports
            .listener
            .try_wait(|_| {})
            .map_err(|e| IpcError::iceoryx("wait", FRAME_EVENT_SERVICE, e))?;
        let ready = self.has_samples();
        self.state.awaited |= ready;
        // A wake-up without samples is the late notification of a frame the
        // poll already took; the caller just looks again.
        Ok(ready || woken > 0)
    }

    fn has_samples(&self) -> bool {
        self.ports.subscriber.has_samples().unwrap_or(false)
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
                    if self.wait_for_frame(silence)? {
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
        let awaited = std::mem::take(&mut self.awaited);
        if let Some(frame) = &newest {
            self.stats.received += 1;
            let header = frame.sample.payload().header;
            self.predictor.on_frame(header.capture_ns, header.sequence);
            if awaited {
                self.predictor
                    .on_awaited_arrival(header.capture_ns, monotonic_now_ns());
            }
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
                self.predictor.reset();
                self.stats.publisher_changes += 1;
                info!(sequence, "frames resumed from a new camera publisher");
            }
            None => info!(sequence, "first frame from camera"),
        }
        self.last = Some((origin, sequence));
    }
}

#[cfg(test)]
mod tests {
    use super::ArrivalPredictor;

    const PERIOD_NS: u64 = 20_000_000;

    /// Frames on a 50 Hz schedule, each late by up to 300 µs (a pseudo-random
    /// but fixed pattern), arriving 40 µs after their stamp.
    fn feed(predictor: &mut ArrivalPredictor, start_ns: u64, frames: u64) -> u64 {
        let mut capture = 0;
        for k in 0..frames {
            let late_ns = (k * 7919 % 13) * 25_000;
            capture = start_ns + k * PERIOD_NS + late_ns;
            predictor.on_frame(capture, k);
            predictor.on_awaited_arrival(capture, capture + 40_000);
        }
        capture
    }

    #[test]
    fn predicts_the_schedule_not_the_last_late_frame() {
        let mut p = ArrivalPredictor::default();
        assert_eq!(p.next_arrival_ns(), None, "nothing known yet");
        let start = 1_000_000_000;
        feed(&mut p, start, 200);
        let period_error = p.period_ns().abs_diff(PERIOD_NS);
        assert!(period_error < 100_000, "period {} ns", p.period_ns());
        // The next frame is due at start + 200 periods (+ its lateness) and
        // arrives 40 µs after its stamp: the prediction sits on the
        // schedule, within the 250 µs polling window of the on-time case.
        let on_time = start + 200 * PERIOD_NS + 40_000;
        let predicted_ns = p.next_arrival_ns().expect("a prediction");
        assert!(
            predicted_ns.abs_diff(on_time) < 250_000,
            "predicted {} µs from the on-time arrival",
            (predicted_ns as i64 - on_time as i64) / 1000
        );
    }

    #[test]
    fn a_restarted_stream_starts_over() {
        let mut p = ArrivalPredictor::default();
        let last = feed(&mut p, 1_000_000_000, 50);
        // A new camera process numbers frames from zero again.
        p.on_frame(last + 5 * PERIOD_NS, 0);
        assert_eq!(p.next_arrival_ns(), None);
        assert_eq!(p.period_ns(), 0);
    }

    #[test]
    fn implausible_periods_and_delays_are_ignored() {
        let mut p = ArrivalPredictor::default();
        // 10 µs apart: faster than any camera; ignored.
        for k in 0..10 {
            p.on_frame(1_000_000 + k * 10_000, k);
            p.on_awaited_arrival(1_000_000 + k * 10_000, 1_000_000 + k * 10_000 + 1000);
        }
        assert_eq!(p.period_ns(), 0);
        assert_eq!(p.next_arrival_ns(), None);
        // An arrival before its own capture stamp (another clock) is ignored.
        let mut q = ArrivalPredictor::default();
        q.on_frame(5_000_000_000, 0);
        q.on_awaited_arrival(5_000_000_000, 4_000_000_000);
        q.on_frame(5_000_000_000 + PERIOD_NS, 1);
        q.on_frame(5_000_000_000 + 2 * PERIOD_NS, 2);
        assert_eq!(q.next_arrival_ns(), None, "no delay known");
    }
}
