//! `rigslam map`: stand-alone edge-map problems: solve one from
//! an edges file, generate one from a simulated drive, compare edge policies.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use rigslam::edge_map::edges_file::{
    read_edges_file, read_positions, write_edges_file, write_positions,
};
use rigslam::edge_map::simulate::{simulate_city, CityOptions};
use rigslam::edge_map::{EdgeMapSolver, EdgePolicy, SolverChoice};

#[derive(clap::Args)]
pub struct MapArgs {
    #[command(subcommand)]
    command: MapCommand,
}

#[derive(clap::Subcommand)]
enum MapCommand {
    /// Solve A L = B for an edges file; write `id x y z` per landmark.
    Solve(SolveArgs),
    /// Simulate a mapping drive and write its fused edges (and the truth).
    Generate(GenerateArgs),
    /// Accuracy and cost of edge policies on one simulated drive.
    Policies(PoliciesArgs),
    /// Exact landmark covariance (eq. 59) against the sub-matrix approximation.
    Covariance(CovarianceArgs),
    /// Laps of one simulated room with drifting odometry: position error
    /// over time of the relative stage alone, of the absolute stage without
    /// and with landmark recognition (per-lap table, optional plot).
    Loop(LoopArgs),
}

#[derive(clap::Args)]
struct LoopArgs {
    #[arg(long, default_value_t = 6)]
    laps: u32,
    /// Odometry drift, m per m driven (along x; half of it against y).
    #[arg(long, default_value_t = 0.01)]
    drift_per_m: f64,
    /// Bits of each landmark's descriptor flipped at every new track.
    #[arg(long, default_value_t = 20)]
    bit_flips: u32,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Edge policy of the map (default: the absolute stage's, frame:5).
    /// This simulator's frames carry independent noise, so unlike real
    /// frames every frame adds information: `frame` or `all` are more
    /// accurate here.
    #[arg(long)]
    policy: Option<EdgePolicy>,
    /// Write the error over time here (.png or .svg).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Print one JSON object (per-lap RMSE and the per-frame errors).
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct CovarianceArgs {
    #[arg(long, default_value_t = 10_000)]
    landmarks: usize,
    /// Landmarks taken as visible: the nearest to the middle landmark.
    #[arg(long, default_value_t = 30)]
    visible: usize,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Method {
    Cholesky,
    Pcg,
}

#[derive(clap::Args)]
struct SolveArgs {
    /// `# landmarks N edges M reference R`, then `i j ex ey ez s00 s01 s02 s11 s12 s22` per line.
    #[arg(long)]
    edges: PathBuf,
    #[arg(long)]
    out: PathBuf,
    #[arg(long, value_enum, default_value = "cholesky")]
    method: Method,
    /// Threads for the factorisation (1: sequential).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// True positions (`id x y z`, relative to the reference) to report the error.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct GenerateArgs {
    #[arg(long, default_value_t = 10_000)]
    landmarks: usize,
    #[arg(long)]
    out: PathBuf,
    /// Write the true positions relative to the reference landmark here.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// all, frame, frame:N, mst or knn:K. With frame nodes the file's
    /// "landmarks" include one node per mapped frame.
    #[arg(long, default_value = "knn:4")]
    policy: EdgePolicy,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(clap::Args)]
struct PoliciesArgs {
    #[arg(long, default_value_t = 5_000)]
    landmarks: usize,
    #[arg(
        long,
        default_value = "all,frame,frame:5,knn:8,knn:4,knn:2,mst",
        value_delimiter = ','
    )]
    policies: Vec<EdgePolicy>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    #[arg(long)]
    json: bool,
}

pub fn run(args: MapArgs) -> anyhow::Result<()> {
    match args.command {
        MapCommand::Solve(a) => solve(a),
        MapCommand::Generate(a) => generate(a),
        MapCommand::Policies(a) => policies(a),
        MapCommand::Covariance(a) => covariance(a),
        MapCommand::Loop(a) => loop_comparison(a),
    }
}

fn loop_comparison(args: LoopArgs) -> anyhow::Result<()> {
    use rigslam::absolute::loop_run::compare_loops;
    use rigslam::absolute::simulate_relative::RoomRunOptions;
    use rigslam::plot::loop_comparison::write_loop_plot;
    anyhow::ensure!(
        (1..=100).contains(&args.laps),
        "--laps {}: between 1 and 100",
        args.laps
    );
    anyhow::ensure!(
        args.drift_per_m.is_finite() && args.drift_per_m.abs() < 0.5,
        "--drift-per-m {}: a finite drift below 0.5 m per m",
        args.drift_per_m
    );
    anyhow::ensure!(
        args.bit_flips <= 256,
        "--bit-flips {}: a descriptor has 256 bits",
        args.bit_flips
    );
    let options = RoomRunOptions {
        laps: f64::from(args.laps),
        fresh_track_ids: true,
        descriptor_bit_flips: Some(args.bit_flips),
        drift_per_m: nalgebra::Vector3::new(args.drift_per_m, -0.5 * args.drift_per_m, 0.0),
        seed: args.seed,
        ..RoomRunOptions::default()
    };
    let defaults = rigslam::absolute::AbsoluteConfig::default();
    let config = rigslam::absolute::AbsoluteConfig {
        solve_mode: rigslam::absolute::SolveMode::Inline,
        policy: args.policy.unwrap_or(defaults.policy),
        ..defaults
    };
    let c = compare_loops(&options, &config);
    let laps: Vec<serde_json::Value> = (0..c.laps)
        .map(|lap| {
            serde_json::json!({
                "lap": lap + 1,
                "relative_rmse_m": c.relative_lap_rmse(lap),
                "without_recognition_rmse_m": c.unrecognised_lap_rmse(lap),
                "with_recognition_rmse_m": c.recognised_lap_rmse(lap),
                "frame_nodes": c.map_per_lap[lap].frame_nodes,
                "map_unknowns": c.map_per_lap[lap].unknowns,
            })
        })
        .collect();
    if let Some(plot) = &args.plot {
        let title = format!(
            "{} laps of a 16 x 10 m room, odometry drift {:.1} % of distance, edges {}",
            c.laps,
            100.0 * args.drift_per_m * 1.25f64.sqrt(),
            config.policy
        );
        write_loop_plot(plot, &c, &title).map_err(|e| anyhow::anyhow!(e))?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "laps": laps,
                "recognised": c.recognised,
                "false_recognitions": c.false_recognitions,
                "frames": c.t_s.len(),
                "errors": c,
            })
        );
        return Ok(());
    }
    println!("| lap | relative stage alone m | absolute, no recognition m | absolute with recognition m | its map: frame nodes, unknowns |");
    println!("|---|---|---|---|---|");
    for l in &laps {
        println!(
            "| {} | {:.3} | {:.3} | {:.3} | {}, {} |",
            l["lap"],
            l["relative_rmse_m"].as_f64().unwrap_or(f64::NAN),
            l["without_recognition_rmse_m"].as_f64().unwrap_or(f64::NAN),
            l["with_recognition_rmse_m"].as_f64().unwrap_or(f64::NAN),
            l["frame_nodes"],
            l["map_unknowns"],
        );
    }
    println!(
        "{} track ids recognised as earlier landmarks, {} of them wrong; {} frames",
        c.recognised,
        c.false_recognitions,
        c.t_s.len()
    );
    Ok(())
}

fn solve(args: SolveArgs) -> anyhow::Result<()> {
    let t = Instant::now();
    let problem = read_edges_file(&args.edges)?;
    let read_ms = t.elapsed().as_secs_f64() * 1e3;
    let choice = match args.method {
        Method::Cholesky => SolverChoice::Cholesky,
        Method::Pcg => SolverChoice::ConjugateGradient,
    };
    let mut solver = EdgeMapSolver::new(choice, args.threads);
    let (positions, report) = solver
        .solve(&problem)
        .with_context(|| format!("solving {}", args.edges.display()))?;
    write_positions(&args.out, &positions)?;
    let error = match &args.truth {
        Some(path) => {
            let truth = read_positions(path)?;
            anyhow::ensure!(
                truth.len() == positions.len(),
                "{} has {} landmarks, the problem {}",
                path.display(),
                truth.len(),
                positions.len()
            );
            let sq: f64 = truth
                .iter()
                .zip(&positions)
                .map(|(a, b)| (a - b).norm_squared())
                .sum();
            Some((sq / truth.len() as f64).sqrt())
        }
        None => None,
    };
    if args.json {
        let mut json = serde_json::json!({
            "landmarks": problem.landmark_count,
            "edges": problem.edges.len(),
            "assemble_ms": report.assemble_ms,
            "factor_ms": report.factor_ms,
            "solve_ms": report.solve_ms,
            "total_ms": report.total_ms,
            "symbolic_ms": report.symbolic_ms,
            "order_ms": report.order_ms,
            "read_ms": read_ms,
            "method": report.method,
            "factor_nnz": report.factor_nnz,
            "cg_iterations": report.cg_iterations,
            "threads": args.threads,
        });
        if let Some(e) = error {
            json["rmse_vs_truth_m"] = e.into();
        }
        println!("{json}");
    } else {
        println!(
            "{} landmarks, {} edges ({}): assemble {:.1} ms, factor {:.1} ms (symbolic {:.1}), solve {:.1} ms, total {:.1} ms; read {:.1} ms",
            problem.landmark_count, problem.edges.len(), report.method, report.assemble_ms, report.factor_ms, report.symbolic_ms, report.solve_ms, report.total_ms, read_ms
        );
        if let Some(e) = error {
            println!("RMSE against truth: {e:.4} m");
        }
    }
    Ok(())
}

fn generate(args: GenerateArgs) -> anyhow::Result<()> {
    let options = CityOptions {
        landmarks: args.landmarks,
        policy: args.policy,
        seed: args.seed,
        ..Default::default()
    };
    let sim = simulate_city(&options);
    write_edges_file(&args.out, &sim.problem)?;
    if let Some(path) = &args.truth {
        write_positions(path, &sim.truth_relative_m())?;
    }
    tracing::info!(
        "{} landmarks, {} edges from {} frames ({} measurements, policy {}) written to {}",
        sim.problem.landmark_count,
        sim.problem.edges.len(),
        sim.frames,
        sim.measurements,
        args.policy,
        args.out.display()
    );
    Ok(())
}

fn policies(args: PoliciesArgs) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    for policy in &args.policies {
        let sim = simulate_city(&CityOptions {
            landmarks: args.landmarks,
            policy: *policy,
            seed: args.seed,
            ..Default::default()
        });
        let (positions, report) =
            EdgeMapSolver::new(SolverChoice::Cholesky, 1).solve(&sim.problem)?;
        let truth = sim.truth_relative_m();
        let is_landmark = |id: u32| !sim.frame_node[id as usize];
        let sq: Vec<f64> = truth
            .iter()
            .zip(&positions)
            .zip(&sim.frame_node)
            .filter(|(_, &frame)| !frame)
            .map(|((a, b), _)| (a - b).norm_squared())
            .collect();
        let rmse_m = (sq.iter().sum::<f64>() / sq.len() as f64).sqrt();
        // Error of neighbouring landmarks relative to each other, what a
        // robot localising sees: over the landmark-pair edges, or for frame
        // nodes over the pairs of landmarks one frame saw (consecutive ids).
        let mut pairs: Vec<(u32, u32)> = sim
            .problem
            .edges
            .iter()
            .filter(|e| is_landmark(e.i) && is_landmark(e.j))
            .map(|e| (e.i, e.j))
            .collect();
        let mut seen_by: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
        for e in &sim.problem.edges {
            match (is_landmark(e.i), is_landmark(e.j)) {
                (false, true) => seen_by.entry(e.i).or_default().push(e.j),
                (true, false) => seen_by.entry(e.j).or_default().push(e.i),
                _ => {}
            }
        }
        for seen in seen_by.values_mut() {
            seen.sort_unstable();
            pairs.extend(seen.windows(2).map(|w| (w[0], w[1])));
        }
        let local: f64 = pairs
            .iter()
            .map(|&(i, j)| {
                let est = positions[j as usize] - positions[i as usize];
                let tru = truth[j as usize] - truth[i as usize];
                (est - tru).norm_squared()
            })
            .sum::<f64>()
            / pairs.len().max(1) as f64;
        rows.push(serde_json::json!({
            "policy": policy.to_string(),
            "landmarks": sim.problem.landmark_count,
            "frames": sim.frames,
            "measurements": sim.measurements,
            "edges": sim.problem.edges.len(),
            "fuse_ms": sim.fuse_ms,
            "solve_total_ms": report.total_ms,
            "factor_nnz": report.factor_nnz,
            "rmse_m": rmse_m,
            "edge_rmse_m": local.sqrt(),
        }));
    }
    if args.json {
        println!("{}", serde_json::Value::Array(rows));
    } else {
        println!("| policy | edges | measurements | fuse ms | solve ms | factor nnz | landmark RMSE m | edge RMSE m |");
        println!("|---|---|---|---|---|---|---|---|");
        for r in rows {
            println!(
                "| {} | {} | {} | {:.1} | {:.1} | {} | {:.4} | {:.4} |",
                r["policy"].as_str().unwrap_or(""),
                r["edges"],
                r["measurements"],
                r["fuse_ms"].as_f64().unwrap_or(0.0),
                r["solve_total_ms"].as_f64().unwrap_or(0.0),
                r["factor_nnz"],
                r["rmse_m"].as_f64().unwrap_or(0.0),
                r["edge_rmse_m"].as_f64().unwrap_or(0.0)
            );
        }
    }
    Ok(())
}

fn covariance(args: CovarianceArgs) -> anyhow::Result<()> {
    use rigslam::edge_map::covariance::{exact_covariance, submatrix_covariance};
    use rigslam::edge_map::BlockLaplacian;
    let sim = simulate_city(&CityOptions {
        landmarks: args.landmarks,
        seed: args.seed,
        ..Default::default()
    });
    let mut solver = EdgeMapSolver::new(SolverChoice::Cholesky, 1);
    solver.solve(&sim.problem)?;
    let centre = sim.truth_m[sim.truth_m.len() / 2];
    let mut by_distance: Vec<(f64, u32)> = sim
        .truth_m
        .iter()
        .enumerate()
        .map(|(id, p)| ((p - centre).norm(), id as u32))
        .filter(|(_, id)| *id != sim.problem.reference)
        .collect();
    by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
    let visible: Vec<u32> = by_distance.iter().take(args.visible).map(|v| v.1).collect();
    let t = Instant::now();
    let exact = exact_covariance(
        solver.factor().expect("Cholesky solve keeps its factor"),
        &sim.problem,
        &visible,
    );
    let exact_ms = t.elapsed().as_secs_f64() * 1e3;
    let laplacian = BlockLaplacian::assemble(&sim.problem);
    println!("{} landmarks, {} visible around landmark {}; exact blocks by solving 3m columns: {exact_ms:.1} ms", args.landmarks, visible.len(), sim.truth_m.len() / 2);
    println!("| sub-matrix rings | visible dim | ms | rel. Frobenius diff | trace ratio approx/exact | mean marginal sigma approx / exact m |");
    println!("|---|---|---|---|---|---|");
    let sigma = |m: &nalgebra::DMatrix<f64>| {
        (0..m.nrows()).map(|k| m[(k, k)].sqrt()).sum::<f64>() / m.nrows() as f64
    };
    for hops in [0usize, 1, 2, 4, 8] {
        let t = Instant::now();
        let approx = submatrix_covariance(&laplacian, &sim.problem, &visible, hops);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "| {hops} | {} | {ms:.1} | {:.3} | {:.4} | {:.4} / {:.4} |",
            approx.nrows(),
            (&approx - &exact).norm() / exact.norm(),
            approx.trace() / exact.trace(),
            sigma(&approx),
            sigma(&exact)
        );
    }
    Ok(())
}
