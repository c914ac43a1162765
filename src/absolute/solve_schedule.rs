//! Where and when the absolute stage's map is solved, as one state per
//! [`SolveMode`]: a worker called inline, a thread of the stage's own
//! (background and pipelined modes) with the solve in flight and a
//! deferred trigger, or a request waiting for the caller (manual mode).

use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::JoinHandle;

use nalgebra::Vector3;

use super::map_worker::{MapSolveRequest, MapSolveWorker, RobustWeights, SolvedMap};
use crate::edge_map::edge::{EdgeChanges, EdgeMap};
use crate::edge_map::problem::{MapProblem, ProblemMirror};
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
    /// The daemon on live frames never waits
    /// ([`super::AbsoluteStage::never_wait_for_solves`]): a late solve is
    /// installed on the first frame after it is done.
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
            SolveMode::Background | SolveMode::Pipelined => Self::thread(worker(), None),
        }
    }

    /// The threaded state, its thread solving with `worker` (`gate`: see
    /// [`SolveThread::spawn`]).
    fn thread(worker: MapSolveWorker, gate: Option<Receiver<()>>) -> Self {
        MapSolver::Thread {
            thread: SolveThread::spawn(worker, gate),
            in_flight: false,
            deferred: false,
        }
    }

    /// The thread of the background and pipelined modes, whose every solve
    /// first waits for a token on the returned channel (tests: a solve
    /// that finishes exactly when the test says).
    #[cfg(test)]
    pub(super) fn gated(solver: SolverChoice, robust: Option<RobustWeights>) -> (Self, Sender<()>) {
        let mut worker = MapSolveWorker::new(solver, 1);
        worker.robust = robust;
        let (gate_tx, gate_rx) = mpsc::channel();
        (Self::thread(worker, Some(gate_rx)), gate_tx)
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

/// How much nicer the map solve thread is than the thread that starts it
/// (the frame path). On a robot computer with one core for rigslam, a
/// solve at the frame path's priority takes half the core from a frame
/// whenever both run; 10 steps nicer, the frame path gets about 90 % of
/// it, and the solve still runs while the frame path waits for the next
/// image. A pipelined frame that waits for its solve sleeps, so the solve
/// then has the core to itself.
pub const MAP_SOLVE_NICE: i32 = 10;

impl SolveThread {
    /// Starts `rigslam-map-solve`, which keeps a mirror of the map's
    /// problem from the edge-map changes it receives and solves it with `worker`.
    /// `gate`: each solve first waits for a token on it (tests).
    fn spawn(mut worker: MapSolveWorker, gate: Option<Receiver<()>>) -> Self {
        let (request_tx, request_rx) = mpsc::channel::<ThreadRequest>();
        let (result_tx, result_rx) = mpsc::channel();
        let handle = std::thread::Builder::new()
            .name("rigslam-map-solve".into())
            .spawn(move || {
                crate::thread_priority::lower_this_threads_priority(MAP_SOLVE_NICE);
                let mut mirror = ProblemMirror::new();
                for request in request_rx {
                    if let Some(gate) = &gate {
                        if gate.recv().is_err() {
                            break;
                        }
                    }
                    mirror.apply_changes(&request.changes);
                    let request = MapSolveRequest {
                        version: request.version,
                        problem: mirror.problem(0),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::absolute::{AbsoluteConfig, AbsoluteStage};

    /// The nice values of this process's threads called `name`.
    fn nice_of_threads(name: &str) -> Vec<i64> {
        let mut found = Vec::new();
        for task in std::fs::read_dir("/proc/self/task").expect("/proc/self/task") {
            let dir = task.expect("a task").path();
            let comm = std::fs::read_to_string(dir.join("comm")).unwrap_or_default();
            if comm.trim() != name {
                continue;
            }
            let stat = std::fs::read_to_string(dir.join("stat")).expect("stat");
            // Fields after the command name in parentheses; nice is the
            // 19th field, the 17th after it.
            let rest = &stat[stat.rfind(')').expect("comm") + 2..];
            let nice = rest.split_whitespace().nth(16).expect("nice field");
            found.push(nice.parse().expect("a number"));
        }
        found
    }

    #[test]
    fn the_map_solve_thread_yields_to_the_frame_path() {
        let stage = AbsoluteStage::new(AbsoluteConfig {
            solve_mode: SolveMode::Pipelined,
            ..AbsoluteConfig::default()
        });
        // This thread's nice value: the solve thread's must be 10 more.
        let own = std::fs::read_to_string("/proc/thread-self/stat").expect("stat");
        let rest = &own[own.rfind(')').expect("comm") + 2..];
        let own: i64 = rest
            .split_whitespace()
            .nth(16)
            .expect("nice")
            .parse()
            .expect("nice");
        let want = (own + i64::from(MAP_SOLVE_NICE)).min(19);
        // The thread lowers its priority as it starts (the kernel cuts
        // the name to 15 bytes).
        let mut nice = Vec::new();
        for _ in 0..200 {
            nice = nice_of_threads("rigslam-map-sol");
            if nice.contains(&want) {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        drop(stage);
        assert!(
            nice.contains(&want),
            "map solve threads' nice values: {nice:?}, wanted {want} (this thread: {own})"
        );
    }
}
