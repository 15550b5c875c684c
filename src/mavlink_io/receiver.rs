//! The `mavlink-rx` thread: reads the link, answers the autopilot's TIMESYNC
//! requests at once (so its round trip stays short) in the clock `usec` is
//! in, feeds replies to our requests into the offset estimator, and counts
//! autopilot HEARTBEATs.
//!
//! Takes the link that `mavlink-tx` opened; reports a failing link back to it
//! (`Shared::mark_broken`) and waits for the next one.

use std::sync::atomic::Ordering;
use std::sync::{Arc, PoisonError};
use std::time::Duration;

use mavlink::dialects::common::{MavAutopilot, MavMessage};
use mavlink::MavHeader;

use super::link::Link;
use super::messages;
use super::stats::bump;
use super::timesync::{TimesyncEvent, RESYNC_AFTER};
use super::Shared;
use crate::clock::monotonic_now_ns;

/// Wait while there is no (working) link.
const IDLE: Duration = Duration::from_millis(20);

/// The thread body.
pub(crate) fn run(shared: Arc<Shared>) {
    while !shared.stopping() {
        let Some((generation, link)) = shared.current_link() else {
            std::thread::sleep(IDLE);
            continue;
        };
        if shared.broken_generation.load(Ordering::Acquire) == generation {
            std::thread::sleep(IDLE);
            continue;
        }
        match link.recv() {
            Ok(Some((header, message))) => {
                let now_ns = monotonic_now_ns();
                handle(&shared, &link, generation, &header, &message, now_ns);
            }
            Ok(None) => {}
            Err(error) => shared.mark_broken(generation, &error),
        }
    }
}

fn handle(
    shared: &Shared,
    link: &Link,
    generation: u64,
    header: &MavHeader,
    message: &MavMessage,
    now_ns: u64,
) {
    let ours = shared.header;
    if header.system_id == ours.system_id && header.component_id == ours.component_id {
        return; // our own message echoed back (broadcast setups)
    }
    match message {
        MavMessage::TIMESYNC(d) if d.tc1 == 0 => {
            let for_us = (d.target_system == 0 || u32::from(d.target_system) == ours.system_id)
                && (d.target_component == 0 || d.target_component == ours.component_id);
            if !for_us {
                return;
            }
            let tc1 = shared.public_ns(now_ns);
            let target_system = u8::try_from(header.system_id).unwrap_or(0);
            let reply = messages::timesync(tc1, d.ts1, target_system, header.component_id);
            match link.send(&ours, &reply) {
                Ok(true) => bump(&shared.counters.timesync_replies_sent),
                Ok(false) => {}
                Err(error) => shared.mark_broken(generation, &error),
            }
        }
        MavMessage::TIMESYNC(d) => {
            if !shared.config.timesync {
                return;
            }
            let event = shared
                .timesync
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .reply_received(d.tc1, d.ts1, now_ns as i64);
            let counters = &shared.counters;
            match event {
                TimesyncEvent::Sample(sample) => {
                    bump(&counters.timesync_samples);
                    let first = counters.timesync_samples.load(Ordering::Relaxed) == 1;
                    if first {
                        tracing::info!(
                            offset_ns = sample.offset_ns,
                            rtt_ns = sample.rtt_ns,
                            "TIMESYNC: first offset"
                        );
                    } else {
                        tracing::trace!(
                            offset_ns = sample.offset_ns,
                            rtt_ns = sample.rtt_ns,
                            "TIMESYNC sample"
                        );
                    }
                }
                TimesyncEvent::Outlier(sample) => {
                    bump(&counters.timesync_rejected);
                    // Warn on the 1st, 2nd, 4th, 8th ... so a flood of bad
                    // replies cannot flood the log.
                    let n = counters.timesync_rejected.load(Ordering::Relaxed);
                    if n.is_power_of_two() {
                        tracing::warn!(
                            offset_ns = sample.offset_ns,
                            rtt_ns = sample.rtt_ns,
                            estimate_ns = ?shared.estimate().map(|e| e.offset_ns),
                            rejected = n,
                            "TIMESYNC reply outside the plausibility bound of the estimate: \
                             ignored unless {RESYNC_AFTER} agreeing ones come in a row"
                        );
                    }
                }
                TimesyncEvent::Rejected => {
                    bump(&counters.timesync_rejected);
                    tracing::debug!(tc1 = d.tc1, ts1 = d.ts1, "TIMESYNC reply not used");
                }
                TimesyncEvent::Resync { .. } => {
                    // The estimator logged it; the pose clock slews toward it.
                    bump(&counters.timesync_samples);
                    bump(&counters.timesync_resyncs);
                }
            }
        }
        MavMessage::HEARTBEAT(d) if d.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID => {
            bump(&shared.counters.autopilot_heartbeats);
            if shared.counters.autopilot_heartbeats.load(Ordering::Relaxed) == 1 {
                tracing::info!(system_id = header.system_id, autopilot = ?d.autopilot, "autopilot heard");
            }
        }
        _ => {}
    }
}
