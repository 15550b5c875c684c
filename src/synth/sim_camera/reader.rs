//! The simulator link of the `sim:` camera: one thread that asks the
//! autopilot (ArduPilot SITL) for SIM_STATE at [`STATE_RATE_HZ`] and keeps
//! the newest one.
//!
//! Takes an open MAVLink [`Link`] and the origin (fixed, or taken from the
//! first state and then kept for every later connection); gives out
//! [`TruthSample`]s: the vehicle's state with its arrival time on
//! CLOCK_MONOTONIC, the instant the sample is taken to describe. The
//! SIM_STATE request (MAV_CMD_SET_MESSAGE_INTERVAL to the autopilot that
//! sent a HEARTBEAT) is repeated while no state arrives, so an autopilot
//! that reboots streams again. A broken link ends the thread; the camera
//! then reports the source disconnected and the camera loop reopens it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mavlink::dialects::common::{
    MavAutopilot, MavCmd, MavMessage, COMMAND_LONG_DATA, SIM_STATE_DATA,
};
use mavlink::MavHeader;

use super::truth::{position_of, StateError, VehicleState};
use crate::camera::GeoPoint;
use crate::clock::monotonic_now_ns;
use crate::mavlink_io::link::Link;
use crate::mavlink_io::messages::{heartbeat, LinkState};
use crate::service::signals::{shutdown_requested, SLEEP_SLICE};

/// SIM_STATE rate asked of the autopilot, Hz: at least twice the camera
/// rate, so a capture instant is at most about 10 ms after a state.
pub const STATE_RATE_HZ: f64 = 100.0;
/// How long without a SIM_STATE before the request is sent again.
const REQUEST_AGAIN: Duration = Duration::from_secs(1);
/// Our MAVLink identity: the autopilot's usual system, a camera component
/// (MAV_COMP_ID_CAMERA).
const HEADER: MavHeader = MavHeader {
    system_id: 1,
    component_id: 100,
    sequence: 0,
};

/// One state and when it arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    /// The vehicle's state.
    pub state: VehicleState,
    /// Arrival of the SIM_STATE, CLOCK_MONOTONIC ns.
    pub arrival_ns: u64,
    /// States received so far on this link (1 for the first).
    pub count: u64,
}

/// What the reader shares with the camera.
#[derive(Debug, Default)]
struct Slot {
    latest: Option<TruthSample>,
    /// Why the link ended; set once, when the thread stops on an error.
    broken: Option<String>,
    /// SIM_STATEs that could not be used.
    rejected: u64,
}

struct Shared {
    slot: Mutex<Slot>,
    fresh: Condvar,
    stop: AtomicBool,
}

/// Why no state was returned.
#[derive(Debug, Clone, PartialEq)]
pub enum FeedError {
    /// Nothing newer than asked for arrived in time.
    Timeout,
    /// The link broke (the reason).
    Broken(String),
    /// A stop signal arrived while waiting.
    Stopped,
}

/// The reader thread and the newest state.
pub struct TruthFeed {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl TruthFeed {
    /// Starts the reader on `link`. `origin` is filled from the first
    /// state when empty.
    pub fn start(link: Link, origin: Arc<OnceLock<GeoPoint>>) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot::default()),
            fresh: Condvar::new(),
            stop: AtomicBool::new(false),
        });
        let thread = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("sim-truth".into())
                .spawn(move || run(&link, &shared, &origin))?
        };
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// The newest sample that arrived at or after `newer_than_ns`, waiting
    /// up to `timeout` for one (in slices, to see a stop signal).
    pub fn wait_newer(
        &self,
        newer_than_ns: u64,
        timeout: Duration,
    ) -> Result<TruthSample, FeedError> {
        let deadline = Instant::now() + timeout;
        let mut slot = self
            .shared
            .slot
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        loop {
            if let Some(reason) = &slot.broken {
                return Err(FeedError::Broken(reason.clone()));
            }
            if let Some(sample) = slot.latest.filter(|s| s.arrival_ns >= newer_than_ns) {
                return Ok(sample);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(FeedError::Timeout);
            }
            if shutdown_requested() {
                return Err(FeedError::Stopped);
            }
            slot = self
                .shared
                .fresh
                .wait_timeout(slot, left.min(SLEEP_SLICE))
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }

    /// SIM_STATEs received that could not be used.
    pub fn rejected(&self) -> u64 {
        self.shared
            .slot
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .rejected
    }
}

impl Drop for TruthFeed {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            // The link's receive returns within its 100 ms read timeout.
            let _ = thread.join();
        }
    }
}

/// MAV_CMD_SET_MESSAGE_INTERVAL for SIM_STATE at [`STATE_RATE_HZ`].
fn request(target: (u8, u8)) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        param1: 108.0, // SIM_STATE
        param2: (1e6 / STATE_RATE_HZ) as f32,
        command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
        target_system: target.0,
        target_component: target.1,
        ..COMMAND_LONG_DATA::default()
    })
}

fn run(link: &Link, shared: &Shared, origin: &OnceLock<GeoPoint>) {
    let mut autopilot: Option<(u8, u8)> = None;
    let mut last_request: Option<Instant> = None;
    let mut last_state: Option<Instant> = None;
    let mut last_heartbeat: Option<Instant> = None;
    let mut count = 0u64;
    let result = loop {
        if shared.stop.load(Ordering::Relaxed) {
            break Ok(());
        }
        let now = Instant::now();
        let due = |t: Option<Instant>, every: Duration| t.is_none_or(|t| now - t >= every);
        if due(last_heartbeat, Duration::from_secs(1)) {
            last_heartbeat = Some(now);
            if let Err(e) = link.send(&HEADER, &heartbeat(LinkState::Active)) {
                break Err(e.to_string());
            }
        }
        if let Some(target) = autopilot {
            if due(last_state, REQUEST_AGAIN) && due(last_request, REQUEST_AGAIN) {
                last_request = Some(now);
                tracing::info!(
                    system = target.0,
                    rate_hz = STATE_RATE_HZ,
                    "sim camera: asking the autopilot for SIM_STATE"
                );
                if let Err(e) = link.send(&HEADER, &request(target)) {
                    break Err(e.to_string());
                }
            }
        }
        match link.recv() {
            Ok(Some((header, MavMessage::HEARTBEAT(hb))))
                if hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID =>
            {
                if autopilot.is_none() {
                    tracing::info!(
                        system = header.system_id,
                        component = header.component_id,
                        "sim camera: autopilot found"
                    );
                }
                // MAVLink system ids are one byte; the crate widens them.
                autopilot = u8::try_from(header.system_id)
                    .ok()
                    .map(|system| (system, header.component_id));
            }
            Ok(Some((_, MavMessage::SIM_STATE(m)))) => {
                let arrival_ns = monotonic_now_ns();
                last_state = Some(Instant::now());
                count += 1;
                store(shared, origin, &m, arrival_ns, count);
            }
            Ok(_) => {}
            Err(e) => break Err(e.to_string()),
        }
    };
    if let Err(reason) = result {
        tracing::warn!(%reason, "sim camera: simulator link lost");
        let mut slot = shared.slot.lock().unwrap_or_else(PoisonError::into_inner);
        slot.broken = Some(reason);
        shared.fresh.notify_all();
    }
}

fn store(
    shared: &Shared,
    origin: &OnceLock<GeoPoint>,
    m: &SIM_STATE_DATA,
    arrival_ns: u64,
    count: u64,
) {
    let origin = match origin.get() {
        Some(o) => o,
        None => match position_of(m) {
            Ok(p) => origin.get_or_init(|| {
                tracing::info!(
                    lat_deg = p.lat_deg,
                    lon_deg = p.lon_deg,
                    alt_m = p.alt_m,
                    "sim camera: origin (local NED 0, 0, 0) is the vehicle's first position"
                );
                p
            }),
            Err(e) => return reject(shared, m, &e),
        },
    };
    let state = match VehicleState::from_sim_state(m, origin) {
        Ok(state) => state,
        Err(e) => return reject(shared, m, &e),
    };
    let mut slot = shared.slot.lock().unwrap_or_else(PoisonError::into_inner);
    slot.latest = Some(TruthSample {
        state,
        arrival_ns,
        count,
    });
    drop(slot);
    shared.fresh.notify_all();
}

fn reject(shared: &Shared, m: &SIM_STATE_DATA, error: &StateError) {
    let mut slot = shared.slot.lock().unwrap_or_else(PoisonError::into_inner);
    slot.rejected += 1;
    if slot.rejected == 1 {
        tracing::warn!(
            %error,
            lat_int = m.lat_int,
            lon_int = m.lon_int,
            alt = m.alt,
            "sim camera: a SIM_STATE could not be used (logged once; counted)"
        );
    }
}
