//! `cell bench ipc`: one-way latency of a full 640x480 cloud between two processes,
//! over iceoryx2 and over a Unix domain stream socket, measured in the same run.
//!
//! Method: the sender stamps `CLOCK_MONOTONIC` (shared by all processes on Linux)
//! into the message just before handing it over; the receiver, a separate process,
//! reads the header and `touch_points` points spread over the cloud (the first and
//! the last among them), then takes its own stamp; the difference is the one-way
//! latency. The receiver acknowledges each message (checksum of what it read) before
//! the sender sends the next, so there is never more than one message in flight.
//! Rounds interleave the three transports so drift on a busy machine hits all alike:
//!
//! - `iceoryx2_zero_copy`: the cloud is written into a loaned shared-memory sample
//!   before the stamp (as a camera renders into it); sending passes a reference.
//! - `iceoryx2_copy_in`: the stamp is taken before copying the cloud from a private
//!   buffer into the loaned sample (a producer that did not write in place).
//! - `unix_socket`: the same bytes (header-sized prefix + points) written with one
//!   `write_all` on a `SOCK_STREAM` socket and read with `read_exact` into a buffer.
//! - `iceoryx2_zero_copy_polling`: as `iceoryx2_zero_copy`, but the receiver spins on
//!   `try_receive` instead of blocking on the wake-up event: the transport without
//!   the kernel wake-up the other three pay, as long as the spinning receiver keeps
//!   its core (on a loaded machine it loses it and does worse than blocking).
//!
//! The receivers of the first three block (event listener, `read`), as the cell's
//! stages do.

use super::domain::Domain;
use super::payloads::{
    CloudAck, CloudHeader, Frame, Intrinsics, Point, MAX_CLOUD_HEIGHT, MAX_CLOUD_WIDTH,
};
use super::peer::{Linger, PeerProcess, PeerRole, PeerSpec};
use super::services::CloudTopic;
use super::stage::{CloudSample, CloudSubscriber, Stage};
use super::{monotonic_now_ns, IpcError};
use crate::geometry::Pose;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Trial id of the receiver's "ready" acknowledgement.
pub const READY_TRIAL_ID: u64 = u64::MAX;

/// Bytes before the points in a socket message (the size of [`CloudHeader`]).
const SOCKET_HEADER_BYTES: usize = std::mem::size_of::<CloudHeader>();
/// Bytes of one point on the socket.
const POINT_BYTES: usize = std::mem::size_of::<Point>();
/// Bytes of a socket acknowledgement: trial id, latency (ns), points, checksum bits.
const SOCKET_ACK_BYTES: usize = 32;

/// Instructions of the receiving process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReceiverSpec {
    /// Unix socket the sender listens on.
    pub socket: PathBuf,
    /// Rounds to receive (warm-up included); each is two iceoryx2 clouds received
    /// blocking, one socket message, and one iceoryx2 cloud received by polling.
    pub rounds: usize,
    /// Points the receiver reads per cloud, spread evenly, first and last included.
    pub touch_points: usize,
}

/// Options of a benchmark run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BenchOptions {
    /// Measured rounds (each: one message per transport).
    pub rounds: usize,
    /// Rounds before measuring (page faults, caches, connections).
    pub warmup: usize,
    /// Points the receiver reads per cloud.
    pub touch_points: usize,
    /// Seed of the random cloud.
    pub seed: u64,
    /// Longest wait for the peer at any step.
    pub timeout: Duration,
}

/// One-way latencies of the measured rounds (ns), one per round and transport.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchSamples {
    /// Points per cloud.
    pub points: usize,
    /// Bytes per message (header + points).
    pub bytes: usize,
    /// iceoryx2, cloud written in place before the stamp.
    pub iceoryx2_zero_copy_ns: Vec<u64>,
    /// iceoryx2, stamp before copying the cloud into shared memory.
    pub iceoryx2_copy_in_ns: Vec<u64>,
    /// Unix domain stream socket.
    pub unix_socket_ns: Vec<u64>,
    /// iceoryx2 zero copy, receiver polling instead of blocking.
    pub iceoryx2_zero_copy_polling_ns: Vec<u64>,
}

/// `k` indices spread evenly over `0..n`, first and last included (all when k >= n).
pub fn touched_indices(n: usize, k: usize) -> Vec<usize> {
    match (n, k) {
        (0, _) | (_, 0) => Vec::new(),
        (_, 1) => vec![n - 1],
        _ if k >= n => (0..n).collect(),
        _ => (0..k).map(|j| j * (n - 1) / (k - 1)).collect(),
    }
}

/// [`touched_indices`] of `k` points, kept for the last cloud size.
struct Touch {
    k: usize,
    n: usize,
    indices: Vec<usize>,
}

impl Touch {
    fn new(k: usize) -> Touch {
        Touch {
            k,
            n: 0,
            indices: Vec::new(),
        }
    }

    fn indices(&mut self, n: usize) -> &[usize] {
        if n != self.n {
            self.n = n;
            self.indices = touched_indices(n, self.k);
        }
        &self.indices
    }
}

/// Sum of `x + y + z` (as f64, in index order) over the points at `indices`.
pub fn checksum(points: &[Point], indices: &[usize]) -> f64 {
    indices
        .iter()
        .map(|&i| {
            let p = points[i];
            p.x as f64 + p.y as f64 + p.z as f64
        })
        .sum()
}

/// [`checksum`] over points stored as native-endian f32 triples in `bytes`.
fn checksum_bytes(bytes: &[u8], indices: &[usize]) -> f64 {
    let f = |at: usize| {
        f32::from_ne_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]) as f64
    };
    indices
        .iter()
        .map(|&i| {
            let at = i * POINT_BYTES;
            f(at) + f(at + 4) + f(at + 8)
        })
        .sum()
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_ne_bytes(b)
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    let mut b = [0u8; 4];
    b.copy_from_slice(&bytes[at..at + 4]);
    u32::from_ne_bytes(b)
}

fn io_error(path: &Path) -> impl Fn(std::io::Error) -> IpcError + '_ {
    move |source| IpcError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The receiving process: acknowledges every cloud with what it read.
pub(crate) fn run_receiver(
    domain: &Domain,
    spec: &ReceiverSpec,
    idle: Duration,
) -> Result<Linger, IpcError> {
    let stage = Stage::start(domain, "bench-receiver")?;
    let clouds = stage.cloud_subscriber(CloudTopic::Camera)?;
    let acks = stage.publisher::<CloudAck>()?;
    let mut stream = UnixStream::connect(&spec.socket).map_err(io_error(&spec.socket))?;
    stream
        .set_read_timeout(Some(idle))
        .map_err(io_error(&spec.socket))?;
    acks.send(&CloudAck {
        trial_id: READY_TRIAL_ID,
        ..CloudAck::default()
    })?;

    let max_points = (MAX_CLOUD_WIDTH * MAX_CLOUD_HEIGHT) as usize;
    let mut header = vec![0u8; SOCKET_HEADER_BYTES];
    let mut body = vec![0u8; max_points * POINT_BYTES];
    let mut touch = Touch::new(spec.touch_points);
    let mut socket_touch = Touch::new(spec.touch_points);
    let mut receive_and_ack = |poll: bool| -> Result<(), IpcError> {
        let cloud = if poll {
            receive_polling(&clouds, idle)?
        } else {
            clouds.receive_timeout(idle)?
        }
        .ok_or_else(|| IpcError::Peer(format!("bench receiver: no cloud within {idle:?}")))?;
        let h = *cloud.header();
        let points = cloud.points();
        if h.len() != points.len() {
            return Err(IpcError::CloudShape {
                width: h.width,
                height: h.height,
                points: points.len(),
                max: max_points,
            });
        }
        let sum = checksum(points, touch.indices(points.len()));
        let now = monotonic_now_ns();
        let n = points.len() as u64;
        drop(cloud);
        acks.send(&CloudAck {
            trial_id: h.trial_id,
            stamp_ns: now,
            cloud_stamp_ns: h.stamp_ns,
            points: n,
            checksum: sum,
        })?;
        Ok(())
    };
    for _ in 0..spec.rounds {
        receive_and_ack(false)?;
        receive_and_ack(false)?;
        stream
            .read_exact(&mut header)
            .map_err(io_error(&spec.socket))?;
        let (trial_id, stamp) = (u64_at(&header, 0), u64_at(&header, 8));
        let n = u32_at(&header, 16) as usize * u32_at(&header, 20) as usize;
        if n == 0 || n > max_points {
            return Err(IpcError::Peer(format!(
                "bench receiver: socket message of {n} points"
            )));
        }
        let body = &mut body[..n * POINT_BYTES];
        stream.read_exact(body).map_err(io_error(&spec.socket))?;
        let sum = checksum_bytes(body, socket_touch.indices(n));
        let now = monotonic_now_ns();
        let mut ack = [0u8; SOCKET_ACK_BYTES];
        ack[0..8].copy_from_slice(&trial_id.to_ne_bytes());
        ack[8..16].copy_from_slice(&now.wrapping_sub(stamp).to_ne_bytes());
        ack[16..24].copy_from_slice(&(n as u64).to_ne_bytes());
        ack[24..32].copy_from_slice(&sum.to_bits().to_ne_bytes());
        stream.write_all(&ack).map_err(io_error(&spec.socket))?;
        receive_and_ack(true)?;
    }
    Ok(Box::new((clouds, acks, stage)))
}

/// Spins on `try_receive` until a cloud arrives or `timeout` passes.
fn receive_polling(
    clouds: &CloudSubscriber,
    timeout: Duration,
) -> Result<Option<CloudSample>, IpcError> {
    let deadline = Instant::now() + timeout;
    let mut spins = 0u32;
    loop {
        if let Some(cloud) = clouds.try_receive()? {
            return Ok(Some(cloud));
        }
        spins = spins.wrapping_add(1);
        if spins % 1024 == 0 && Instant::now() >= deadline {
            return Ok(None);
        }
        std::hint::spin_loop();
    }
}

/// The benchmark's cloud: 640x480 seeded random points within 2 m of the camera.
fn random_cloud(seed: u64) -> Vec<Point> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..(MAX_CLOUD_WIDTH * MAX_CLOUD_HEIGHT) as usize)
        .map(|_| {
            Point::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(0.3..2.0),
            )
        })
        .collect()
}

fn bench_header(trial_id: u64, stamp_ns: u64) -> CloudHeader {
    let intrinsics = Intrinsics {
        fx: 525.0,
        fy: 525.0,
        cx: 319.5,
        cy: 239.5,
    };
    CloudHeader::new(
        trial_id,
        stamp_ns,
        MAX_CLOUD_WIDTH,
        MAX_CLOUD_HEIGHT,
        intrinsics,
        Frame::CameraOptical,
        &Pose::identity(),
    )
}

/// Runs the benchmark: starts `cell_exe` as the receiving process in a temporary
/// isolated domain, measures, stops it and removes the domain. `on_round` is called
/// after every round (for a progress bar).
pub fn run_sender(
    cell_exe: &Path,
    options: &BenchOptions,
    on_round: &mut dyn FnMut(),
) -> Result<BenchSamples, IpcError> {
    let domain = Domain::temporary("bench-ipc")?;
    let result = sender_in_domain(&domain, cell_exe, options, on_round);
    let removed = domain.remove();
    let samples = result?;
    removed?;
    Ok(samples)
}

fn sender_in_domain(
    domain: &Domain,
    cell_exe: &Path,
    options: &BenchOptions,
    on_round: &mut dyn FnMut(),
) -> Result<BenchSamples, IpcError> {
    let root = domain.root();
    crate::fsio::create_dir_all(&root)?;
    let socket_path = root.join("bench.sock");
    let listener = UnixListener::bind(&socket_path).map_err(io_error(&socket_path))?;

    let stage = Stage::start(domain, "bench-sender")?;
    let clouds = stage.cloud_publisher(CloudTopic::Camera)?;
    let acks = stage.subscriber::<CloudAck>()?;
    let total_rounds = options.warmup + options.rounds;
    let spec = PeerSpec {
        domain: domain.spec(),
        idle_timeout_s: options.timeout.as_secs_f64(),
        role: PeerRole::BenchReceiver(ReceiverSpec {
            socket: socket_path.clone(),
            rounds: total_rounds,
            touch_points: options.touch_points,
        }),
    };
    let mut peer = PeerProcess::spawn(cell_exe, &spec)?;
    let ready = acks.receive_timeout(options.timeout)?;
    if ready.map(|a| a.trial_id) != Some(READY_TRIAL_ID) {
        return Err(IpcError::Peer(format!(
            "bench receiver (pid {}) not ready within {:?}: {ready:?}",
            peer.id(),
            options.timeout
        )));
    }
    // The receiver connected before it said ready, so accept does not block.
    let (mut stream, _) = listener.accept().map_err(io_error(&socket_path))?;
    stream
        .set_read_timeout(Some(options.timeout))
        .map_err(io_error(&socket_path))?;

    let points = random_cloud(options.seed);
    let indices = touched_indices(points.len(), options.touch_points);
    let expected = checksum(&points, &indices);
    let mut wire = vec![0u8; SOCKET_HEADER_BYTES + points.len() * POINT_BYTES];
    wire[16..20].copy_from_slice(&MAX_CLOUD_WIDTH.to_ne_bytes());
    wire[20..24].copy_from_slice(&MAX_CLOUD_HEIGHT.to_ne_bytes());
    for (i, p) in points.iter().enumerate() {
        let at = SOCKET_HEADER_BYTES + i * POINT_BYTES;
        wire[at..at + 4].copy_from_slice(&p.x.to_ne_bytes());
        wire[at + 4..at + 8].copy_from_slice(&p.y.to_ne_bytes());
        wire[at + 8..at + 12].copy_from_slice(&p.z.to_ne_bytes());
    }

    let check = |what: &str, trial_id: u64, got_id: u64, got_points: u64, got_sum: f64| {
        if got_id != trial_id
            || got_points != points.len() as u64
            || got_sum.to_bits() != expected.to_bits()
        {
            return Err(IpcError::Peer(format!(
                "{what}: acknowledgement of trial {got_id} with {got_points} points, checksum {got_sum}; \
                 expected trial {trial_id}, {} points, checksum {expected}",
                points.len()
            )));
        }
        Ok(())
    };
    let await_ack = |trial_id: u64| -> Result<u64, IpcError> {
        let ack = acks.receive_timeout(options.timeout)?.ok_or_else(|| {
            IpcError::Peer(format!(
                "no acknowledgement of trial {trial_id} within {:?}",
                options.timeout
            ))
        })?;
        check("iceoryx2", trial_id, ack.trial_id, ack.points, ack.checksum)?;
        Ok(ack.stamp_ns.saturating_sub(ack.cloud_stamp_ns))
    };

    let mut samples = BenchSamples {
        points: points.len(),
        bytes: wire.len(),
        iceoryx2_zero_copy_ns: Vec::with_capacity(options.rounds),
        iceoryx2_copy_in_ns: Vec::with_capacity(options.rounds),
        unix_socket_ns: Vec::with_capacity(options.rounds),
        iceoryx2_zero_copy_polling_ns: Vec::with_capacity(options.rounds),
    };
    for round in 0..total_rounds {
        let measured = round >= options.warmup;
        let base = 4 * round as u64;
        let send_zero_copy = |trial_id: u64| -> Result<u64, IpcError> {
            // The cloud is in shared memory before the clock starts.
            let mut loan = clouds.loan_copy(bench_header(trial_id, 0), &points)?;
            loan.header_mut().stamp_ns = monotonic_now_ns();
            loan.send()?;
            await_ack(trial_id)
        };

        let zero_copy = send_zero_copy(base + 1)?;

        // Copy in: the clock starts before the cloud is copied into shared memory.
        let start = monotonic_now_ns();
        clouds
            .loan_copy(bench_header(base + 2, start), &points)?
            .send()?;
        let copy_in = await_ack(base + 2)?;

        // Socket: the same bytes through the kernel.
        wire[0..8].copy_from_slice(&(base + 3).to_ne_bytes());
        wire[8..16].copy_from_slice(&monotonic_now_ns().to_ne_bytes());
        stream.write_all(&wire).map_err(io_error(&socket_path))?;
        let mut ack = [0u8; SOCKET_ACK_BYTES];
        stream
            .read_exact(&mut ack)
            .map_err(io_error(&socket_path))?;
        let sum = f64::from_bits(u64_at(&ack, 24));
        check(
            "unix socket",
            base + 3,
            u64_at(&ack, 0),
            u64_at(&ack, 16),
            sum,
        )?;
        let socket = u64_at(&ack, 8);

        let polling = send_zero_copy(base + 4)?;

        if measured {
            samples.iceoryx2_zero_copy_ns.push(zero_copy);
            samples.iceoryx2_copy_in_ns.push(copy_in);
            samples.unix_socket_ns.push(socket);
            samples.iceoryx2_zero_copy_polling_ns.push(polling);
        }
        on_round();
    }
    drop(stream);
    peer.finish(options.timeout)?;
    Ok(samples)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn touched_indices_spread_and_include_both_ends() {
        assert_eq!(touched_indices(10, 1), vec![9]);
        assert_eq!(touched_indices(10, 2), vec![0, 9]);
        assert_eq!(touched_indices(10, 4), vec![0, 3, 6, 9]);
        assert_eq!(touched_indices(3, 16), vec![0, 1, 2]);
        assert!(touched_indices(0, 4).is_empty());
        let many = touched_indices(307_200, 16);
        assert_eq!((many.len(), many[0], many[15]), (16, 0, 307_199));
    }

    #[test]
    fn checksum_of_bytes_equals_checksum_of_points() {
        let points = random_cloud(3);
        let indices = touched_indices(points.len(), 100);
        let bytes: Vec<u8> = points
            .iter()
            .flat_map(|p| [p.x.to_ne_bytes(), p.y.to_ne_bytes(), p.z.to_ne_bytes()].concat())
            .collect();
        let by_hand: f64 = indices
            .iter()
            .map(|&i| points[i].x as f64 + points[i].y as f64 + points[i].z as f64)
            .sum();
        assert_eq!(checksum(&points, &indices), by_hand);
        assert_eq!(checksum_bytes(&bytes, &indices), by_hand);
    }
}
