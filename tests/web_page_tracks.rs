//! The page draws tracks: the page's real server (`web::WebServer`) fed by a publisher on
//! which the test streams `TRACKS` (as the tracker task does, with tracks known exactly) and
//! `ZONES`, opened in headless Chromium by tests/python/web_tracks.py.
//! Each track is drawn as a `[data-track="<id>"]` element labelled with its id, west to east
//! as in the site, and the People panel counts them.
//!
//! Needs SCANFUSE_TEST_PYTHON (with Playwright; the venv .ci/run builds) and /usr/bin/chromium
//! (.ci/run installs it); skips without them, except under CI.

use crate::common;

use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::time::Duration;

use scanfuse::daemon::config::WebConfig;
use scanfuse::daemon::protocol::{Message, Poses, Saved, Status, Track, Tracks, ZoneCount, Zones};
use scanfuse::daemon::socket::{Publisher, Refused, StatusSource};
use scanfuse::fuse::OccupancyGrid;
use scanfuse::web::{PageSource, WebServer};

const CHROMIUM: &str = "/usr/bin/chromium";

struct Site;

impl StatusSource for Site {
    fn status(&self) -> Status {
        Status {
            site: "people".into(),
            uptime_s: 1.0,
            queue_drops: 0,
            sensors: vec![],
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        }
    }
    fn poses(&self) -> Poses {
        Poses {
            anchor: "a".into(),
            sensors: vec![],
            building_from_site: None,
            site_from_zone: None,
        }
    }
    fn reregister(&self, _: &str) -> Result<String, Refused> {
        Err(Refused("not here".into()))
    }
    fn save(&self) -> Result<Saved, Refused> {
        Err(Refused("not here".into()))
    }
}

impl PageSource for Site {
    fn occupancy(&self) -> Option<OccupancyGrid> {
        None
    }
    fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
        Vec::new()
    }
}

fn track(id: u64, x_m: f64, y_m: f64) -> Track {
    Track {
        id,
        x_m,
        y_m,
        vx_m_s: 0.5,
        vy_m_s: 0.0,
        sigma_m: 0.05,
        age_s: 2.0,
        sensors: vec!["a".into()],
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_draws_each_track_with_its_id() {
    let test = "the_page_draws_each_track_with_its_id";
    let Some(python) = common::test_python(test) else {
        return;
    };
    if !Path::new(CHROMIUM).exists() {
        assert!(
            std::env::var_os("CI").is_none(),
            "{CHROMIUM} is missing under CI; .ci/run installs Debian's chromium"
        );
        eprintln!("{test}: skipped: no {CHROMIUM} (apt-get install chromium)");
        return;
    }
    let config = WebConfig {
        listen: Some("127.0.0.1:0".parse().unwrap()),
        ..WebConfig::default()
    };
    let server = WebServer::bind(&config).await.unwrap().expect("a page");
    let url = server.url();
    let publisher = Publisher::new(64);
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let source: Arc<dyn PageSource> = Arc::new(Site);
    let served = tokio::spawn(server.run(source, publisher.clone(), stop_rx));
    // Two people walking east, 2 m apart, at 10 Hz until the browser is done.
    let (done_tx, mut done_rx) = tokio::sync::oneshot::channel::<()>();
    let feeder = {
        let publisher = publisher.clone();
        tokio::spawn(async move {
            let mut t_ns: u64 = 1_000_000_000;
            let mut tick = tokio::time::interval(Duration::from_millis(100));
            loop {
                tokio::select! {
                    _ = &mut done_rx => return,
                    _ = tick.tick() => {}
                }
                let dx = (t_ns - 1_000_000_000) as f64 * 5e-10;
                publisher.people(Message::Tracks(Tracks {
                    t_ns,
                    tracks: vec![track(3, 1.0 + dx, 0.0), track(8, 3.0 + dx, 0.0)],
                }));
                publisher.people(Message::Zones(Zones {
                    t_ns,
                    zones: vec![ZoneCount {
                        id: "hall".into(),
                        count: 2,
                        tracks: vec![3, 8],
                    }],
                }));
                t_ns += 100_000_000;
            }
        })
    };
    let out = tokio::task::spawn_blocking(move || {
        Command::new(python)
            .arg(common::repo().join("tests/python/web_tracks.py"))
            .args(["--url", &url, "--ids", "3,8", "--browser", CHROMIUM])
            .arg("--screenshot")
            .arg(common::repo().join("target/web-page-tracks.png"))
            .env("PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD", "1")
            .output()
            .expect("run the browser")
    })
    .await
    .unwrap();
    let _ = done_tx.send(());
    feeder.await.unwrap();
    let _ = stop_tx.send(true);
    served.await.unwrap();
    assert!(
        out.status.success(),
        "the browser test failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).expect("a JSON summary");
    let drawn = &summary["drawn"];
    assert_eq!(drawn.as_object().unwrap().len(), 2, "{summary}");
    assert_eq!(drawn["3"]["text"], "t3", "{summary}");
    assert_eq!(drawn["8"]["text"], "t8", "{summary}");
    let (x3, x8) = (
        drawn["3"]["x"].as_f64().unwrap(),
        drawn["8"]["x"].as_f64().unwrap(),
    );
    assert!(x8 > x3 + 10.0, "8 is 2 m east of 3: {summary}");
    let counts = summary["counts"].as_str().unwrap();
    assert!(
        counts.contains("2 people") && counts.contains("hall 2"),
        "{counts}"
    );
}
