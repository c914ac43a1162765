//! Where and when the absolute stage's map is solved, as one state per
//! [`SolveMode`]: a worker called inline, a thread of the stage's own
//! (background and pipelined modes) with the solve in flight and a
//! deferred trigger, or a request waiting for the caller (manual mode).

use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::JoinHandle;

use nalgebra::Vector3;

use super::map_worker::{MapSolveRequest, MapSolveWorker, RobustWeights, SolvedMap};
use crate::edge_map::edge::{EdgeChanges, EdgeMap};
use crate::edge_map::problem::MapProblem;
use crate::edge_map::solve::SolverChoice;
use crate::edge_map::EdgeMapError;

/// Where the map solve runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolveMode {
    /// In `push`, on the frame that triggers it (deterministic: tests,
    /// offline runs). The frame after a trigger sees the new map.
    Inline,
    /// On a background thread the stage owns. A finished solve is picked
    /// up by the next `push`; a trigger while one runs is deferred until it
    /// returns. Frames never wait for it, so which map a frame sees
    /// depends on timing (a replay faster than real time sees older maps).
    Background,
    /// On the background thread, installed on a fixed schedule: the solve
    /// requested at frame n is installed at frame n + K (K =
    /// `solve_every_frames`), the frame that requests the next one, which
    /// waits for it if it is not done. A run is repeatable and a replay
    /// faster than real time sees the maps a live run would; live at
    /// 20 Hz with K = 5 a frame waits only if a solve takes over 250 ms.
    Pipelined,
    /// The caller runs it: [`super::AbsoluteStage::take_solve_request`] hands out
    /// the request, any thread solves it with a [`MapSolveWorker`], and
    /// [`super::AbsoluteStage::install_solved_map`] installs the result.
    Manual,
}

/// The solve state of one [`SolveMode`].
pub(super) enum MapSolver {
    /// [`SolveMode::Inline`]: the stage solves on the frame that triggers.
    Inline(MapSolveWorker),
    /// [`SolveMode::Background`] and [`SolveMode::Pipelined`]: the stage's
    /// thread solves; at most one solve runs, a trigger meanwhile waits.
    Thread {
        thread: SolveThread,
        /// A request was sent and its result not yet taken.
        in_flight: bool,
        /// A solve was triggered while one ran: request it when that returns.
        deferred: bool,
    },
    /// [`SolveMode::Manual`]: the request waits for the caller.
    Manual { request: Option<MapSolveRequest> },
}

/// The map solve thread and its two channels.
pub(super) struct SolveThread {
    requests: Option<Sender<ThreadRequest>>,
    results: Receiver<Result<SolvedMap, EdgeMapError>>,
    handle: Option<JoinHandle<()>>,
}

/// What the frame path sends the map thread: only the edges changed since
/// the last request (the thread keeps its own copy of the edge map), so
/// that the frame never copies or sorts the whole map.
struct ThreadRequest {
    version: u64,
    changes: EdgeChanges,
    previous_m: Vec<Option<Vector3<f64>>>,
    covariance_of: Vec<u32>,
}

impl Drop for SolveThread {
    fn drop(&mut self) {
        self.requests.take();
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

impl MapSolver {
    /// The state for `mode`, starting the thread where it has one; the
    /// worker solves with `solver` on `threads` threads, reweighting by
    /// `robust`.
    pub(super) fn new(
        mode: SolveMode,
        solver: SolverChoice,
        threads: usize,
        robust: Option<RobustWeights>,
    ) -> Self {
        let worker = || {
            let mut worker = MapSolveWorker::new(solver, threads);
            worker.robust = robust;
            worker
        };
        match mode {
            SolveMode::Inline => MapSolver::Inline(worker()),
            SolveMode::Manual => MapSolver::Manual { request: None },
            SolveMode::Background | SolveMode::Pipelined => MapSolver::Thread {
                thread: SolveThread::spawn(worker()),
                in_flight: false,
                deferred: false,
            },
        }
    }

    /// Whether the edge map must record its changes for the thread.
    pub(super) fn needs_edge_changes(&self) -> bool {
        matches!(self, MapSolver::Thread { .. })
    }

    /// Whether a threaded solve is running.
    pub(super) fn in_flight(&self) -> bool {
        matches!(
            self,
            MapSolver::Thread {
                in_flight: true,
                ..
            }
        )
    }

    /// The inline worker (inline mode only).
    pub(super) fn inline_worker(&mut self) -> Option<&mut MapSolveWorker> {
        match self {
            MapSolver::Inline(worker) => Some(worker),
            _ => None,
        }
    }

    /// The result of the threaded solve, if it has returned (`wait`: waits
    /// for a running one), and whether a trigger was deferred meanwhile.
    pub(super) fn finished(
        &mut self,
        wait: bool,
    ) -> Option<(Result<SolvedMap, EdgeMapError>, bool)> {
        let MapSolver::Thread {
            thread,
            in_flight,
            deferred,
        } = self
        else {
            return None;
        };
        let result = if wait {
            if !*in_flight {
                return None;
            }
            thread.results.recv().ok()?
        } else {
            thread.results.try_recv().ok()?
        };
        *in_flight = false;
        Some((result, std::mem::take(deferred)))
    }

    /// Defers a trigger while a threaded solve runs; true if it did.
    pub(super) fn defer_if_busy(&mut self) -> bool {
        match self {
            MapSolver::Thread {
                in_flight: true,
                deferred,
                ..
            } => {
                *deferred = true;
                true
            }
            _ => false,
        }
    }

    /// Hands the solve of `edges` over: to the thread (only the changes),
    /// to the caller, or solves it here and returns the result (inline).
    pub(super) fn submit(
        &mut self,
        version: u64,
        edges: &mut EdgeMap,
        previous_m: Vec<Option<Vector3<f64>>>,
        covariance_of: Vec<u32>,
    ) -> Option<Result<SolvedMap, EdgeMapError>> {
        let whole = |edges: &EdgeMap, previous_m, covariance_of| MapSolveRequest {
            version,
            problem: MapProblem::from_edge_map(edges, 0),
            previous_m,
            covariance_of,
        };
        match self {
            MapSolver::Thread {
                thread, in_flight, ..
            } => {
                let sender = thread.requests.as_ref().expect("sender lives until drop");
                let request = ThreadRequest {
                    version,
                    changes: edges.take_changes(),
                    previous_m,
                    covariance_of,
                };
                if sender.send(request).is_ok() {
                    *in_flight = true;
                }
                None
            }
            MapSolver::Inline(worker) => {
                Some(worker.solve(whole(edges, previous_m, covariance_of)))
            }
            MapSolver::Manual { request } => {
                *request = Some(whole(edges, previous_m, covariance_of));
                None
            }
        }
    }

    /// Manual mode: the request waiting to be solved, if any.
    pub(super) fn take_request(&mut self) -> Option<MapSolveRequest> {
        match self {
            MapSolver::Manual { request } => request.take(),
            _ => None,
        }
    }
}

impl SolveThread {
    /// Starts `rigslam-map-solve`, which keeps a mirror of the edge map
    /// from the changes it receives and solves it with `worker`.
    fn spawn(mut worker: MapSolveWorker) -> Self {
        let (request_tx, request_rx) = mpsc::channel::<ThreadRequest>();
        let (result_tx, result_rx) = mpsc::channel();
        let handle = std::thread::Builder::new()
            .name("rigslam-map-solve".into())
            .spawn(move || {
                let mut mirror = EdgeMap::new();
                for request in request_rx {
                    mirror.apply_changes(&request.changes);
                    let request = MapSolveRequest {
                        version: request.version,
                        problem: MapProblem::from_edge_map(&mirror, 0),
                        previous_m: request.previous_m,
                        covariance_of: request.covariance_of,
                    };
                    if result_tx.send(worker.solve(request)).is_err() {
                        break;
                    }
                }
            })
            .expect("spawning the map solve thread");
        SolveThread {
            requests: Some(request_tx),
            results: result_rx,
            handle: Some(handle),
        }
    }
}
