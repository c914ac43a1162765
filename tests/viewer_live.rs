//! The live view as an operator meets it: `rigslamd --viewer` replays the
//! bundled EuRoC sequence at its recorded pace while a WebSocket client
//! speaking Foxglove's protocol (`foxglove.sdk.v1`: server info,
//! advertise, subscribe, binary message data) subscribes and receives
//! poses, transforms, a camera calibration, images, the tracks over them
//! and the landmark cloud, decoded through
//! the schemas the server advertised. A second client connects, subscribes
//! to the images and never reads: the daemon still publishes every pose.
//! A second daemon asked for the same port says so and runs on without
//! the view.

use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};

use prost::Message as _;
use rigslam::recording::schemas::PoseEstimateProto;
use rigslam::shared_data;
use serde_json::{json, Value};
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket};

#[path = "common/daemon.rs"]
mod daemon;
use daemon::{rigslamd, Daemon};

/// `rigslamd` replaying `dataset` with the viewer on `viewer`.
fn start_daemon(dataset: &Path, root: &Path, prefix: &str, viewer: &str, report: &Path) -> Daemon {
    let mut command = rigslamd();
    command
        .arg("--replay")
        .arg(dataset)
        .args(["--service-prefix", prefix, "--viewer", viewer])
        .arg("--root-path")
        .arg(root)
        .arg("--report")
        .arg(report);
    Daemon::start(command)
}

/// A Foxglove WebSocket client: connected, with the channels advertised.
struct Client {
    ws: WebSocket<TcpStream>,
    /// Advertised channels by topic: (id, schema name).
    channels: std::collections::BTreeMap<String, (u64, String)>,
}

impl Client {
    fn connect(port: u16) -> Client {
        let stream = TcpStream::connect(("127.0.0.1", port)).expect("connect");
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .expect("timeout");
        let mut request = format!("ws://127.0.0.1:{port}")
            .into_client_request()
            .expect("request");
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            "foxglove.sdk.v1".parse().expect("header"),
        );
        let (ws, response) = tungstenite::client(request, stream).expect("handshake");
        assert_eq!(
            response.headers()["Sec-WebSocket-Protocol"],
            "foxglove.sdk.v1"
        );
        let mut client = Client {
            ws,
            channels: Default::default(),
        };
        // serverInfo, then the advertisement of every channel.
        let deadline = Instant::now() + Duration::from_secs(10);
        while client.channels.len() < 8 {
            assert!(
                Instant::now() < deadline,
                "advertised: {:?}",
                client.channels
            );
            if let Message::Text(text) = client.ws.read().expect("read") {
                let v: Value = serde_json::from_str(&text).expect("json");
                if v["op"] == "advertise" {
                    for c in v["channels"].as_array().expect("channels") {
                        client.channels.insert(
                            c["topic"].as_str().expect("topic").to_owned(),
                            (
                                c["id"].as_u64().expect("id"),
                                c["schemaName"].as_str().expect("schema").to_owned(),
                            ),
                        );
                    }
                }
            }
        }
        client
    }

    /// Subscribes to `topics` with subscription ids 1, 2, ...; returns
    /// the topic of each id.
    fn subscribe(&mut self, topics: &[&str]) -> Vec<String> {
        let subscriptions: Vec<Value> = topics
            .iter()
            .enumerate()
            .map(|(i, t)| json!({"id": i + 1, "channelId": self.channels[*t].0}))
            .collect();
        let text = json!({"op": "subscribe", "subscriptions": subscriptions}).to_string();
        self.ws.send(Message::text(text)).expect("subscribe");
        topics.iter().map(|t| t.to_string()).collect()
    }

    /// The next message data: (subscription id, payload).
    fn next(&mut self) -> Option<(u32, Vec<u8>)> {
        loop {
            match self.ws.read() {
                Ok(Message::Binary(data)) if data.first() == Some(&1) => {
                    let id = u32::from_le_bytes(data[1..5].try_into().expect("4"));
                    return Some((id, data[13..].to_vec()));
                }
                Ok(_) => {}
                Err(_) => return None,
            }
        }
    }
}

#[test]
fn an_operator_sees_poses_transforms_and_images_live() {
    let Some(dataset) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let prefix = format!("viewer_live_{}", std::process::id());
    let report = dir.path().join("report.json");
    let mut daemon = start_daemon(
        &dataset,
        &dir.path().join("iox"),
        &prefix,
        "127.0.0.1:0",
        &report,
    );
    let line = daemon.line(
        "viewer: Foxglove WebSocket on ws://127.0.0.1:",
        Duration::from_secs(30),
    );
    let port: u16 = line
        .split("ws://127.0.0.1:")
        .nth(1)
        .map(|rest| {
            rest.chars()
                .take_while(char::is_ascii_digit)
                .collect::<String>()
        })
        .and_then(|p| p.parse().ok())
        .unwrap_or_else(|| panic!("no port in {line:?}"));

    // A client that subscribes to the images and never reads again.
    let mut stuck = Client::connect(port);
    stuck.subscribe(&["/cam0", "/cam1"]);

    let mut client = Client::connect(port);
    for (topic, schema) in [
        ("/cam0", "foxglove.RawImage"),
        ("/rigslam/pose", "rigslam.PoseEstimate"),
        ("/rigslam/pose_map", "foxglove.PoseInFrame"),
        ("/tf", "foxglove.FrameTransforms"),
        ("/cam0/calibration", "foxglove.CameraCalibration"),
        ("/rigslam/status", "rigslam.Status"),
    ] {
        assert_eq!(client.channels[topic].1, schema, "{topic}");
    }
    let topics = client.subscribe(&[
        "/rigslam/pose",
        "/cam0",
        "/tf",
        "/cam0/calibration",
        "/cam0/tracks",
        "/rigslam/landmarks",
    ]);
    let mut tracks = 0;
    let mut clouds = 0;
    let mut poses: Vec<PoseEstimateProto> = Vec::new();
    let mut images = 0;
    let mut frames = std::collections::BTreeSet::new();
    let mut calibrations = 0;
    while let Some((id, data)) = client.next() {
        match topics[id as usize - 1].as_str() {
            "/rigslam/pose" => poses.push(PoseEstimateProto::decode(&data[..]).expect("pose")),
            "/cam0" => {
                let image = foxglove::messages::RawImage::decode(&data[..]).expect("image");
                assert_eq!((image.width, image.height), (752, 480));
                assert_eq!(image.encoding, "mono8");
                assert_eq!(image.data.len(), 752 * 480);
                images += 1;
            }
            "/tf" => {
                let tf = foxglove::messages::FrameTransforms::decode(&data[..]).expect("tf");
                for t in tf.transforms {
                    frames.insert((t.parent_frame_id, t.child_frame_id));
                }
            }
            "/cam0/tracks" => {
                let a = foxglove::messages::ImageAnnotations::decode(&data[..]).expect("tracks");
                let points = &a.points[0].points;
                assert!(points
                    .iter()
                    .all(|p| (0.0..752.0).contains(&p.x) && (0.0..480.0).contains(&p.y)));
                if points.len() >= 10 {
                    tracks += 1;
                }
            }
            "/rigslam/landmarks" => {
                let c = foxglove::messages::PointCloud::decode(&data[..]).expect("cloud");
                assert_eq!((c.frame_id.as_str(), c.point_stride), ("odom", 12));
                assert_eq!(c.data.len() % 12, 0);
                if c.data.len() >= 10 * 12 {
                    clouds += 1;
                }
            }
            _ => {
                let c = foxglove::messages::CameraCalibration::decode(&data[..]).expect("calib");
                assert_eq!((c.width, c.height, c.k.len()), (752, 480, 9));
                calibrations += 1;
            }
        }
        if poses.len() >= 40 && images >= 5 && calibrations >= 1 && tracks >= 5 && clouds >= 5 {
            break;
        }
    }
    assert!(
        poses.len() >= 40,
        "{} poses, log:\n{}",
        poses.len(),
        daemon.log()
    );
    assert!(images >= 5, "{images} images");
    assert!(
        tracks >= 5 && clouds >= 5,
        "{tracks} track sets, {clouds} clouds"
    );
    assert!(poses.windows(2).all(|w| w[0].t_ns < w[1].t_ns));
    assert!(
        poses
            .iter()
            .all(|p| p.position_world_m.len() == 3
                && p.position_world_m.iter().all(|x| x.is_finite()))
    );
    for pair in [("map", "odom"), ("odom", "body"), ("body", "cam0")] {
        assert!(
            frames.contains(&(pair.0.to_owned(), pair.1.to_owned())),
            "{pair:?} not in {frames:?}"
        );
    }

    // The client that never read held nothing up: every frame got its pose.
    assert!(
        daemon.wait_exit(Duration::from_secs(60)).success(),
        "{}",
        daemon.log()
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(report["poses"], report["frames"], "{report}");
    assert_eq!(report["frames"], 95, "{report}");
    drop(stuck);
}

#[test]
fn a_port_in_use_is_said_and_the_daemon_runs_without_the_view() {
    let Some(dataset) = shared_data::path_or_skip("euroc/V1_01_micro") else {
        return;
    };
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = taken.local_addr().expect("addr").port();
    let dir = tempfile::tempdir().expect("tempdir");
    let report = dir.path().join("report.json");
    let mut daemon = start_daemon(
        &dataset,
        &dir.path().join("iox"),
        &format!("viewer_busy_{}", std::process::id()),
        &format!("127.0.0.1:{port}"),
        &report,
    );
    let said = daemon.line("the viewer cannot listen", Duration::from_secs(30));
    assert!(said.contains(&format!("127.0.0.1:{port}")), "{said}");
    assert!(
        daemon.wait_exit(Duration::from_secs(60)).success(),
        "{}",
        daemon.log()
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(report["poses"], 95, "{report}");
    drop(taken);
}
