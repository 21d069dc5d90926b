//! A zone daemon on Zenoh (`[zenoh]`): one site spread over several machines, each daemon
//! holding one zone of it. This file owns the key space and what a zone puts there. The site
//! daemon that joins zones into one frame (`site_from_zone`) is not built yet (issue 21).
//!
//! Under `scanfuse/<site>/<zone>/` (`<site>` the `[site] name`, `<zone>` the `[zenoh] zone`):
//! - `alive`: a liveliness token, held while the daemon runs. Zenoh withdraws it when the
//!   daemon stops, dies, or its link goes quiet for the lease (1 s here), so the others see
//!   a zone go within a second or two.
//! - `poses`: `{"schema":"scanfuse.zone.poses/1","site","zone","t_ns","poses":{…}}`, where
//!   `poses` is the status socket's `poses` reply (the same fields) in the zone's own frame
//!   (its anchor's), JSON (`application/json`), every second and within 0.25 s of a change.
//! - `status`: likewise `scanfuse.zone.status/1` with the socket's `status` reply, every
//!   second.
//!
//! `t_ns` is the zone's wall clock (UNIX ns) when it published. The schema's number is its
//! major version: a reader refuses one it does not know.

use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;

use super::config::ZenohConfig;
use super::pipeline::Pipeline;
use super::protocol::{Poses, Status};

/// The schema of the `poses` key's payload.
pub const POSES_SCHEMA: &str = "scanfuse.zone.poses/1";
/// The schema of the `status` key's payload.
pub const STATUS_SCHEMA: &str = "scanfuse.zone.status/1";

/// Zenoh's link lease (ms): a peer silent this long is gone, its tokens withdrawn.
const LEASE_MS: u64 = 1000;
/// How often poses are looked at for a change.
const LOOK: Duration = Duration::from_millis(250);
/// How often everything is published even when nothing changed (a daemon that starts later
/// has it within this).
const EVERY: Duration = Duration::from_secs(1);

/// The key of `leaf` (`alive`, `poses`, `status`) of `zone` of `site`.
pub fn key(site: &str, zone: &str, leaf: &str) -> String {
    format!("scanfuse/{site}/{zone}/{leaf}")
}

/// One payload: a schema-named wrapper around a socket reply.
#[derive(Debug, Serialize)]
struct Wrapped<'a> {
    schema: &'static str,
    site: &'a str,
    zone: &'a str,
    t_ns: u64,
    #[serde(flatten)]
    body: Body<'a>,
}

/// The reply a payload carries, under its own key (`poses` or `status`).
#[derive(Debug, Serialize)]
#[serde(untagged)]
enum Body<'a> {
    Poses { poses: &'a Poses },
    Status { status: &'a Status },
}

/// Each sensor: id, registered, pose in mm and thousandths of a degree.
type Placed = Vec<(String, bool, [i64; 3])>;

/// What of the poses counts as a change worth publishing at once: who is placed, and where
/// to the millimetre and the thousandth of a degree (not the ages that tick every second).
fn placed_key(poses: &Poses) -> Placed {
    let q = |v: Option<f64>, per: f64| v.map_or(i64::MIN, |v| (v * per).round() as i64);
    poses
        .sensors
        .iter()
        .map(|s| {
            (
                s.id.clone(),
                s.registered,
                [q(s.x_m, 1e3), q(s.y_m, 1e3), q(s.yaw_deg, 1e3)],
            )
        })
        .collect()
}

fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The Zenoh session config: peer mode, the endpoints given, no multicast scouting, a short
/// lease.
fn session_config(cfg: &ZenohConfig) -> Result<zenoh::Config, String> {
    let list = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    let mut c = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_string()),
        ("scouting/multicast/enabled", "false".to_string()),
        ("connect/endpoints", list(&cfg.connect)),
        ("listen/endpoints", list(&cfg.listen)),
        ("transport/link/tx/lease", LEASE_MS.to_string()),
        ("transport/link/tx/keep_alive", "4".to_string()),
    ] {
        c.insert_json5(key, &value)
            .map_err(|e| format!("Zenoh config {key} = {value}: {e}"))?;
    }
    Ok(c)
}

/// Runs the zone until `stop` resolves: holds its liveliness token and publishes its poses
/// and status. A session that cannot open (an endpoint taken, say) is an error on the log,
/// the socket and the terminal, and the daemon goes on serving its sensors without it.
pub async fn run(
    pipeline: Arc<Pipeline>,
    cfg: ZenohConfig,
    site: String,
    stop: impl std::future::Future<Output = ()>,
) {
    use super::protocol::EventKind;
    use super::socket::StatusSource;
    use zenoh::bytes::Encoding;

    let refuse = |why: String| {
        let line = format!("zone {} is not on Zenoh: {why}", cfg.zone);
        pipeline.set_zenoh(line.clone());
        pipeline.announce(EventKind::Error, None, line);
    };
    let config = match session_config(&cfg) {
        Ok(c) => c,
        Err(e) => return refuse(e),
    };
    let session = match zenoh::open(config).await {
        Ok(s) => s,
        Err(e) => return refuse(format!("the session did not open: {e}")),
    };
    let (alive, poses_key, status_key) = (
        key(&site, &cfg.zone, "alive"),
        key(&site, &cfg.zone, "poses"),
        key(&site, &cfg.zone, "status"),
    );
    let token = match session.liveliness().declare_token(&alive).await {
        Ok(t) => t,
        Err(e) => return refuse(format!("{alive} was not declared: {e}")),
    };
    let publishers = async {
        let poses = session
            .declare_publisher(poses_key.clone())
            .encoding(Encoding::APPLICATION_JSON)
            .await?;
        let status = session
            .declare_publisher(status_key.clone())
            .encoding(Encoding::APPLICATION_JSON)
            .await?;
        Ok::<_, zenoh::Error>((poses, status))
    };
    let (poses_pub, status_pub) = match publishers.await {
        Ok(p) => p,
        Err(e) => return refuse(format!("its publishers were not declared: {e}")),
    };
    let described = cfg.describe(&site);
    tracing::info!("{described}");
    pipeline.set_zenoh(format!("{described} (scanfuse/{site}/{}/…)", cfg.zone));
    let mut look = tokio::time::interval(LOOK);
    let mut last: Option<(std::time::Instant, Placed)> = None;
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = &mut stop => break,
            _ = look.tick() => {}
        }
        let poses = pipeline.poses();
        let placed = placed_key(&poses);
        let due = last
            .as_ref()
            .is_none_or(|(at, before)| at.elapsed() >= EVERY || *before != placed);
        if !due {
            continue;
        }
        let t_ns = now_ns();
        let status = pipeline.status();
        let wrap = |schema, body| {
            serde_json::to_vec(&Wrapped {
                schema,
                site: &site,
                zone: &cfg.zone,
                t_ns,
                body,
            })
        };
        let payloads = (
            wrap(POSES_SCHEMA, Body::Poses { poses: &poses }),
            wrap(STATUS_SCHEMA, Body::Status { status: &status }),
        );
        let (Ok(p), Ok(s)) = payloads else {
            tracing::warn!("the zone's poses or status did not serialise");
            continue;
        };
        if let Err(e) = poses_pub.put(p).await {
            tracing::warn!("publishing {poses_key} failed: {e}");
        }
        if let Err(e) = status_pub.put(s).await {
            tracing::warn!("publishing {status_key} failed: {e}");
        }
        last = Some((std::time::Instant::now(), placed));
    }
    // Withdrawn on purpose, so the others see the zone leave at once rather than at the lease.
    drop(token);
    if let Err(e) = session.close().await {
        tracing::warn!("closing the Zenoh session: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::SensorPose;

    #[test]
    fn a_change_is_who_is_placed_and_where_not_the_clock() {
        let mut a = SensorPose::unregistered("a", "waiting");
        let b = SensorPose::unregistered("b", "waiting");
        let poses = |a: &SensorPose| Poses {
            anchor: "a".into(),
            sensors: vec![a.clone(), b.clone()],
            building_from_site: None,
        };
        let before = placed_key(&poses(&a));
        assert_eq!(before, placed_key(&poses(&a)));
        a.registered = true;
        (a.x_m, a.y_m, a.yaw_deg) = (Some(1.0), Some(2.0), Some(30.0));
        let placed = placed_key(&poses(&a));
        assert_ne!(before, placed);
        a.x_m = Some(1.0004);
        assert_eq!(placed, placed_key(&poses(&a)), "under a millimetre");
        a.x_m = Some(1.002);
        assert_ne!(placed, placed_key(&poses(&a)));
        assert_eq!(key("hall", "east", "poses"), "scanfuse/hall/east/poses");
    }
}
