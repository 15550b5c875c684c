//! The render thread: renders keyframes through a [`Renderer`] and prepares
//! them for the tracker, without ever blocking the tracking thread.
//!
//! Keyframe buffers circulate in a fixed pool: the tracker holds one, the
//! worker fills another, and finished ones travel back through bounded
//! channels, so no keyframe is allocated after start-up.

use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TryRecvError, TrySendError};
use std::thread::JoinHandle;

use crate::geometry::{PinholeCamera, Pose};
use crate::render::{RenderedView, Renderer};
use crate::track::Keyframe;
use crate::track::TrackerConfig;

/// Number of keyframe buffers in circulation.
const POOL: usize = 3;

/// A keyframe request.
#[derive(Debug, Clone, Copy)]
pub struct RenderRequest {
    /// Where to render.
    pub world_from_keyframe: Pose,
    /// Keyframe id to assign.
    pub id: u64,
    /// Capture time of the frame that asked for it.
    pub requested_at_ns: u64,
    /// A relocalization candidate or the start pose, not verified: drawn
    /// from both sides of every triangle, whatever `[render]
    /// cull_back_faces` says, since it may stand inside a box or behind a
    /// wall, where only back faces are seen (culled, a camera inside a box
    /// sees the room through it, and a wrong place can pass the gate: a
    /// look-alike room turned 90 degrees, 1.39 m off, did on the `building`
    /// floor); and to the renderer's whole far limit, where a tracking
    /// keyframe stops at `[keyframe] far_m` (the gate tells look-alike
    /// rooms apart by what it sees through their doors).
    pub candidate: bool,
}

/// A finished keyframe, or the reason it could not be made.
pub type RenderResult = Result<Box<Keyframe>, String>;

/// Handle to the render thread.
pub struct RenderWorker {
    requests: Option<SyncSender<RenderRequest>>,
    results: Receiver<RenderResult>,
    recycle: Option<SyncSender<Box<Keyframe>>>,
    thread: Option<JoinHandle<()>>,
    renderer_name: String,
}

impl RenderWorker {
    /// Starts the thread, which owns `renderer`. Keyframes are drawn to
    /// `keyframe_far_m` (`None`: the renderer's far limit; never beyond
    /// it), candidates to the renderer's far limit.
    pub fn spawn(
        mut renderer: Box<dyn Renderer>,
        camera: &PinholeCamera,
        config: &TrackerConfig,
        keyframe_far_m: Option<f64>,
    ) -> std::io::Result<Self> {
        let pinhole = camera.pinhole();
        let config = config.clone();
        let renderer_name = renderer.name();
        let cull_back_faces = renderer.cull_back_faces();
        let candidate_far_m = renderer.far_m();
        let keyframe_far_m = match (keyframe_far_m, candidate_far_m) {
            (Some(k), Some(c)) => Some(k.min(c)),
            (k, c) => k.or(c),
        };
        let (req_tx, req_rx) = sync_channel::<RenderRequest>(1);
        let (res_tx, res_rx) = sync_channel::<RenderResult>(POOL);
        let (recycle_tx, recycle_rx) = sync_channel::<Box<Keyframe>>(POOL);
        for _ in 0..POOL - 1 {
            // The tracker's own first keyframe is the POOL-th buffer; it comes
            // from the first request.
            let _ = recycle_tx.try_send(Box::new(Keyframe::new(&pinhole, &config)));
        }
        let spare = Box::new(Keyframe::new(&pinhole, &config));
        let thread = std::thread::Builder::new()
            .name("star-render".into())
            .spawn(move || {
                let mut view = RenderedView::for_camera(&pinhole);
                let mut spare = Some(spare);
                while let Ok(req) = req_rx.recv() {
                    let mut kf = match spare.take() {
                        Some(kf) => kf,
                        None => match recycle_rx.recv() {
                            Ok(kf) => kf,
                            Err(_) => return,
                        },
                    };
                    let t0 = std::time::Instant::now();
                    renderer.set_cull_back_faces(cull_back_faces && !req.candidate);
                    renderer.set_far_m(if req.candidate {
                        candidate_far_m
                    } else {
                        keyframe_far_m
                    });
                    let result =
                        match renderer.render(&req.world_from_keyframe, &pinhole, &mut view) {
                            Ok(()) => {
                                kf.prepare(&view, req.world_from_keyframe, req.id, &config);
                                kf.requested_at_ns = req.requested_at_ns;
                                tracing::debug!(
                                    id = req.id,
                                    points = kf.point_count(0),
                                    ms = t0.elapsed().as_secs_f64() * 1e3,
                                    "keyframe ready"
                                );
                                Ok(kf)
                            }
                            Err(e) => {
                                spare = Some(kf);
                                Err(format!("{}: {e}", renderer.name()))
                            }
                        };
                    if res_tx.send(result).is_err() {
                        return;
                    }
                }
            })?;
        Ok(Self {
            requests: Some(req_tx),
            results: res_rx,
            recycle: Some(recycle_tx),
            thread: Some(thread),
            renderer_name,
        })
    }

    /// The renderer's name.
    pub fn renderer_name(&self) -> &str {
        &self.renderer_name
    }

    /// Asks for a keyframe without blocking; false if one is already queued.
    pub fn try_request(&self, req: RenderRequest) -> bool {
        match self.requests.as_ref().map(|tx| tx.try_send(req)) {
            Some(Ok(())) => true,
            Some(Err(TrySendError::Full(_))) | Some(Err(TrySendError::Disconnected(_))) | None => {
                false
            }
        }
    }

    /// A finished keyframe, if one is ready (never blocks).
    pub fn try_result(&self) -> Option<RenderResult> {
        match self.results.try_recv() {
            Ok(r) => Some(r),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err("render thread stopped".into())),
        }
    }

    /// Blocks until a keyframe is ready; for start-up and relocalization only.
    pub fn wait_result(&self) -> RenderResult {
        self.results
            .recv()
            .unwrap_or_else(|_| Err("render thread stopped".into()))
    }

    /// Returns a keyframe buffer to the pool.
    pub fn recycle(&self, kf: Box<Keyframe>) {
        if let Some(tx) = &self.recycle {
            let _ = tx.try_send(kf);
        }
    }
}

impl Drop for RenderWorker {
    fn drop(&mut self) {
        // Closing both senders wakes the thread wherever it waits.
        self.requests.take();
        self.recycle.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::*;
    use crate::render::RenderError;

    /// What a render was drawn with: back faces culled, far limit.
    type Drawn = (bool, Option<f64>);

    /// A renderer that draws nothing and records, per render, whether it
    /// was culling back faces and its far limit.
    struct Recorder {
        cull: bool,
        far_m: Option<f64>,
        drawn: Arc<Mutex<Vec<Drawn>>>,
    }

    impl Renderer for Recorder {
        fn name(&self) -> String {
            "recorder".into()
        }

        fn render(
            &mut self,
            _world_from_camera: &Pose,
            _camera: &crate::geometry::PinholeCamera,
            _out: &mut RenderedView,
        ) -> Result<(), RenderError> {
            self.drawn.lock().unwrap().push((self.cull, self.far_m));
            Ok(())
        }

        fn set_cull_back_faces(&mut self, on: bool) {
            self.cull = on;
        }

        fn cull_back_faces(&self) -> bool {
            self.cull
        }

        fn set_far_m(&mut self, far_m: Option<f64>) {
            self.far_m = far_m;
        }

        fn far_m(&self) -> Option<f64> {
            self.far_m
        }
    }

    fn worker(
        cull: bool,
        far_m: Option<f64>,
        keyframe_far_m: Option<f64>,
    ) -> (RenderWorker, Arc<Mutex<Vec<Drawn>>>) {
        let drawn = Arc::new(Mutex::new(Vec::new()));
        let renderer = Recorder {
            cull,
            far_m,
            drawn: Arc::clone(&drawn),
        };
        let camera = crate::geometry::PinholeCamera::new(640, 512, 420.0, 420.0, 319.5, 255.5);
        let worker = RenderWorker::spawn(
            Box::new(renderer),
            &camera,
            &TrackerConfig::default(),
            keyframe_far_m,
        )
        .expect("render thread");
        (worker, drawn)
    }

    fn render(worker: &RenderWorker, id: u64, candidate: bool) {
        assert!(worker.try_request(RenderRequest {
            world_from_keyframe: Pose::identity(),
            id,
            requested_at_ns: 0,
            candidate,
        }));
        let kf = worker.wait_result().expect("a keyframe");
        worker.recycle(kf);
    }

    fn culled(drawn: &Mutex<Vec<Drawn>>) -> Vec<bool> {
        drawn.lock().unwrap().iter().map(|d| d.0).collect()
    }

    fn far_limits(drawn: &Mutex<Vec<Drawn>>) -> Vec<Option<f64>> {
        drawn.lock().unwrap().iter().map(|d| d.1).collect()
    }

    #[test]
    fn candidates_are_drawn_from_both_sides_where_keyframes_cull_back_faces() {
        let (culling, drawn) = worker(true, None, None);
        for (id, candidate) in [(1, false), (2, true), (3, false), (4, true)] {
            render(&culling, id, candidate);
        }
        assert_eq!(culled(&drawn), vec![true, false, true, false]);
        // A renderer configured to draw both sides never culls.
        let (drawing, drawn) = worker(false, None, None);
        for (id, candidate) in [(1, false), (2, true)] {
            render(&drawing, id, candidate);
        }
        assert_eq!(culled(&drawn), vec![false, false]);
    }

    #[test]
    fn keyframes_stop_at_their_far_limit_and_candidates_see_the_renderers() {
        let (near, drawn) = worker(false, Some(30.0), Some(4.0));
        for (id, candidate) in [(1, true), (2, false), (3, true), (4, false)] {
            render(&near, id, candidate);
        }
        assert_eq!(
            far_limits(&drawn),
            vec![Some(30.0), Some(4.0), Some(30.0), Some(4.0)]
        );
        // Never beyond the renderer's own limit.
        let (beyond, drawn) = worker(false, Some(10.0), Some(40.0));
        render(&beyond, 1, false);
        render(&beyond, 2, true);
        assert_eq!(far_limits(&drawn), vec![Some(10.0), Some(10.0)]);
        // A renderer without a limit: keyframes take theirs, candidates none.
        let (unlimited, drawn) = worker(false, None, Some(4.0));
        render(&unlimited, 1, false);
        render(&unlimited, 2, true);
        assert_eq!(far_limits(&drawn), vec![Some(4.0), None]);
        // Without a keyframe limit, both are drawn to the renderer's.
        let (same, drawn) = worker(false, Some(30.0), None);
        render(&same, 1, false);
        render(&same, 2, true);
        assert_eq!(far_limits(&drawn), vec![Some(30.0), Some(30.0)]);
    }
}
