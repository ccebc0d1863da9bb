//! A cross-process virtual CAN bus without kernel CAN.
//!
//! A [`Hub`] listens on an AF_UNIX `SOCK_SEQPACKET` socket at
//! [`hub_socket_path`]`(NAME)` (under `$XDG_RUNTIME_DIR/graspcell-can/`, else
//! `/tmp/graspcell-can-UID/`). Every node connects a [`UnixBus`]; the hub sends
//! each connection a greeting packet, then rebroadcasts every frame a node sends to
//! all other nodes: no loopback, as on CAN without `CAN_RAW_RECV_OWN_MSGS`.
//!
//! One packet carries one frame, encoded like Linux's `struct can_frame` (16
//! bytes: identifier as little-endian u32, DLC, three padding bytes, eight data
//! bytes). The hub drops malformed packets instead of forwarding them, and a node
//! whose receive queue is full loses the frame (like a CAN controller's overrun)
//! instead of stalling the bus.
//!
//! A socket file whose hub died is stale: binding a new hub finds nobody
//! listening, removes it and binds afresh.
//!
//! A hub started with [`Hub::bind_with_faults`] loses or corrupts frames as a
//! [`super::VirtualBus`] does (seeded; drawn once per frame, so every receiver sees the
//! same fault), for hardware-in-loop tests across processes.

use super::virtual_bus::FaultInjector;
use super::{
    BusState, CanBus, CanError, CanFrame, FaultConfig, FaultCounts, PacketError, SEND_TIMEOUT,
    VIRTUAL_PREFIX,
};
use socket2::{Domain, SockAddr, Socket, Type};
use std::io::ErrorKind;
use std::os::unix::fs::{DirBuilderExt, MetadataExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Bytes of one encoded frame (Linux `struct can_frame`).
const PACKET_LEN: usize = 16;
/// The hub's greeting, sent once on every new connection (not 16 bytes long).
const GREETING: &[u8] = b"graspcell-can-hub/1";
/// How long a node waits for the greeting after connecting.
const GREETING_TIMEOUT: Duration = Duration::from_secs(2);
/// Longest path an AF_UNIX address holds (with its terminating NUL).
const MAX_SOCKET_PATH: usize = 107;

/// The socket path of the hub of virtual bus `name`.
pub fn hub_socket_path(name: &str) -> PathBuf {
    let dir = match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir).join("graspcell-can"),
        _ => std::env::temp_dir().join(format!("graspcell-can-{}", crate::sys::user_id())),
    };
    dir.join(format!("{name}.sock"))
}

fn interface_of(name: &str) -> String {
    format!("{VIRTUAL_PREFIX}{name}")
}

/// Checks the name and returns the socket path, creating its directory (mode 0700).
fn prepare_path(name: &str) -> Result<PathBuf, CanError> {
    let interface = interface_of(name);
    super::parse_interface(&interface)?;
    let path = hub_socket_path(name);
    if path.as_os_str().len() > MAX_SOCKET_PATH {
        return Err(CanError::BadInterface {
            interface,
            problem: format!(
                "hub socket path {} exceeds {MAX_SOCKET_PATH} bytes",
                path.display()
            ),
        });
    }
    if let Some(dir) = path.parent() {
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(dir)
            .map_err(|source| CanError::Open {
                interface: interface.clone(),
                error: source,
            })?;
    }
    Ok(path)
}

/// Encodes a frame as one packet (Linux `struct can_frame`, little-endian id).
fn encode_packet(frame: &CanFrame) -> [u8; PACKET_LEN] {
    let mut packet = [0; PACKET_LEN];
    packet[..4].copy_from_slice(&u32::from(frame.id()).to_le_bytes());
    packet[4] = frame.len() as u8;
    packet[8..8 + frame.len()].copy_from_slice(frame.data());
    packet
}

/// Decodes one packet; the error says what is wrong with it.
fn decode_packet(packet: &[u8]) -> Result<CanFrame, PacketError> {
    if packet.len() != PACKET_LEN {
        return Err(PacketError::Length {
            expected: PACKET_LEN,
        });
    }
    let raw_id = u32::from_le_bytes([packet[0], packet[1], packet[2], packet[3]]);
    if raw_id > 0x7FF {
        return Err(PacketError::NotStandard { raw_id });
    }
    let len = usize::from(packet[4]);
    if len > 8 {
        return Err(PacketError::Dlc { dlc: len });
    }
    CanFrame::new(raw_id as u16, &packet[8..8 + len]).map_err(|e| PacketError::Frame(Box::new(e)))
}

fn new_seqpacket_socket() -> std::io::Result<Socket> {
    Socket::new(Domain::UNIX, Type::SEQPACKET, None)
}

use crate::sys::recv_packet;

/// An exclusive `flock` on a lock file beside the socket, held while binding.
struct BindLock(std::fs::File);

impl BindLock {
    fn acquire(path: &Path) -> std::io::Result<BindLock> {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(path)?;
        crate::sys::lock_file_exclusive(&file)?;
        Ok(BindLock(file))
    }
}

impl Drop for BindLock {
    fn drop(&mut self) {
        crate::sys::unlock_file(&self.0);
    }
}

/// The hub of one virtual bus: rebroadcasts frames between connected nodes.
///
/// Dropping it disconnects every node and removes its socket file.
pub struct Hub {
    shared: Arc<HubShared>,
    accept_thread: Option<JoinHandle<()>>,
}

struct HubShared {
    interface: String,
    path: PathBuf,
    identity: (u64, u64),
    listener: Socket,
    stop: AtomicBool,
    exit_when_empty: bool,
    clients: Mutex<Clients>,
    faults: Option<Mutex<FaultInjector>>,
    /// Frames lost because a node's receive queue was full (its controller's
    /// receive overflow).
    overflows: std::sync::atomic::AtomicU64,
}

#[derive(Default)]
struct Clients {
    next_id: u64,
    list: Vec<(u64, Arc<Socket>)>,
}

impl Hub {
    /// Starts the hub of virtual bus `name` on background threads, cleaning a stale
    /// socket file. Fails with [`CanError::Open`] (`AddrInUse`) when a live hub
    /// already serves the bus.
    pub fn bind(name: &str) -> Result<Hub, CanError> {
        Hub::start(name, false, None)
    }

    /// [`Hub::bind`], losing and corrupting forwarded frames as `faults` says
    /// (latency is not supported across processes and must be zero).
    pub fn bind_with_faults(name: &str, faults: FaultConfig) -> Result<Hub, CanError> {
        let interface = interface_of(name);
        faults.validate(&interface)?;
        if !faults.latency.is_zero() {
            return Err(CanError::BadInterface {
                interface,
                problem: format!(
                    "fault latency {:?}: the cross-process hub injects only loss and corruption",
                    faults.latency
                ),
            });
        }
        tracing::info!(bus = %interface, seed = faults.seed, ?faults, "CAN hub faults set");
        Hub::start(name, false, Some(FaultInjector::new(faults)))
    }

    /// Changes the loss and corruption of a hub started with
    /// [`Hub::bind_with_faults`] from the next frame on (the generator and the
    /// counts go on; the seed and latency of `faults` are ignored).
    pub fn set_faults(&self, faults: &FaultConfig) -> Result<(), CanError> {
        let interface = self.shared.interface.clone();
        faults.validate(&interface)?;
        let injector = self
            .shared
            .faults
            .as_ref()
            .ok_or_else(|| CanError::BadInterface {
                interface,
                problem: "the hub was started without fault injection (Hub::bind)".into(),
            })?;
        injector
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .set(faults);
        Ok(())
    }

    /// Counts of frames forwarded, lost and corrupted (all zero without faults).
    pub fn fault_counts(&self) -> FaultCounts {
        self.shared
            .faults
            .as_ref()
            .map(|f| f.lock().unwrap_or_else(|e| e.into_inner()).counts)
            .unwrap_or_default()
    }

    /// Frames lost so far because a node's receive queue was full (a node that
    /// does not read in time loses frames, as a CAN controller's receive buffer
    /// overflows).
    pub fn overflows(&self) -> u64 {
        self.shared.overflows.load(Ordering::SeqCst)
    }

    /// The socket path nodes connect to.
    pub fn path(&self) -> &Path {
        &self.shared.path
    }

    /// Number of nodes connected.
    pub fn clients(&self) -> usize {
        self.shared.lock_clients().list.len()
    }

    fn start(
        name: &str,
        exit_when_empty: bool,
        faults: Option<FaultInjector>,
    ) -> Result<Hub, CanError> {
        let interface = interface_of(name);
        let path = prepare_path(name)?;
        let open_err = |source| CanError::Open {
            interface: interface.clone(),
            error: source,
        };
        // Serialise hub starts (one lock file for the directory), so two starters
        // cannot both remove a stale file and the second unlink the first's socket.
        let _lock = BindLock::acquire(&path.with_file_name(".bind.lock")).map_err(open_err)?;
        let listener = new_seqpacket_socket().map_err(open_err)?;
        let address = SockAddr::unix(&path).map_err(open_err)?;
        if let Err(err) = listener.bind(&address) {
            if err.kind() != ErrorKind::AddrInUse {
                return Err(open_err(err));
            }
            // Somebody's file: a live hub answers, a dead one's file refuses.
            let probe = new_seqpacket_socket().map_err(open_err)?;
            match probe.connect(&address) {
                Ok(()) => {
                    return Err(open_err(std::io::Error::new(
                        ErrorKind::AddrInUse,
                        format!("a hub already serves {}", path.display()),
                    )))
                }
                Err(e) if e.kind() == ErrorKind::ConnectionRefused => {
                    tracing::info!(path = %path.display(), "removing stale CAN hub socket");
                    std::fs::remove_file(&path).map_err(open_err)?;
                    listener.bind(&address).map_err(open_err)?;
                }
                Err(e) => return Err(open_err(e)),
            }
        }
        let meta = std::fs::metadata(&path).map_err(open_err)?;
        listener.listen(16).map_err(open_err)?;
        // A backstop so the accept loop sees `stop` even if shutdown does not wake it.
        listener
            .set_read_timeout(Some(Duration::from_millis(200)))
            .map_err(open_err)?;
        let shared = Arc::new(HubShared {
            interface: interface.clone(),
            path,
            identity: (meta.dev(), meta.ino()),
            listener,
            stop: AtomicBool::new(false),
            exit_when_empty,
            clients: Mutex::new(Clients::default()),
            faults: faults.map(Mutex::new),
            overflows: std::sync::atomic::AtomicU64::new(0),
        });
        tracing::debug!(path = %shared.path.display(), "CAN hub listening");
        let for_thread = Arc::clone(&shared);
        let accept_thread = std::thread::Builder::new()
            .name(format!("can-hub-{name}"))
            .spawn(move || for_thread.accept_loop())
            .map_err(open_err)?;
        Ok(Hub {
            shared,
            accept_thread: Some(accept_thread),
        })
    }

    /// Lets the hub run on, serving until its last node disconnects.
    fn detach(mut self) {
        self.accept_thread.take();
    }
}

impl Drop for Hub {
    fn drop(&mut self) {
        if let Some(thread) = self.accept_thread.take() {
            self.shared.shut_down();
            let _ = thread.join();
        }
    }
}

impl HubShared {
    fn lock_clients(&self) -> MutexGuard<'_, Clients> {
        self.clients.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn accept_loop(self: Arc<Self>) {
        while !self.stop.load(Ordering::SeqCst) {
            let socket = match self.listener.accept() {
                Ok((socket, _)) => Arc::new(socket),
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                    ) =>
                {
                    continue
                }
                Err(e) => {
                    if !self.stop.load(Ordering::SeqCst) {
                        tracing::error!(hub = %self.interface, "accept failed: {e}");
                    }
                    break;
                }
            };
            let id = {
                let mut clients = self.lock_clients();
                if self.stop.load(Ordering::SeqCst) {
                    break;
                }
                if let Err(e) = socket.send_with_flags(GREETING, libc::MSG_NOSIGNAL) {
                    tracing::warn!(hub = %self.interface, "greeting a node failed: {e}");
                    continue;
                }
                let id = clients.next_id;
                clients.next_id += 1;
                clients.list.push((id, Arc::clone(&socket)));
                id
            };
            let hub = Arc::clone(&self);
            let spawned = std::thread::Builder::new()
                .name(format!("can-hub-node-{id}"))
                .spawn(move || hub.serve(id, socket));
            if let Err(e) = spawned {
                tracing::error!(hub = %self.interface, "cannot start a node thread: {e}");
                self.remove_client(id);
            }
        }
        tracing::debug!(hub = %self.interface, "CAN hub stopped");
    }

    /// Forwards every frame node `id` sends to the other nodes until it leaves.
    fn serve(&self, id: u64, socket: Arc<Socket>) {
        let mut buf = [0u8; 64];
        loop {
            let n = match recv_packet(&socket, &mut buf, 0) {
                Ok(0) => break,
                Ok(n) => n,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => break,
            };
            let frame = match decode_packet(&buf[..n]) {
                Ok(frame) => frame,
                Err(problem) => {
                    tracing::warn!(hub = %self.interface, node = id, len = n, "dropped malformed packet: {problem}");
                    continue;
                }
            };
            let packet = match &self.faults {
                None => encode_packet(&frame),
                Some(faults) => {
                    let injected = faults
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .inject(&frame);
                    match injected {
                        Some(frame) => encode_packet(&frame),
                        None => continue,
                    }
                }
            };
            let clients = self.lock_clients();
            for (other, peer) in &clients.list {
                if *other == id {
                    continue;
                }
                match peer.send_with_flags(&packet, libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL) {
                    Ok(_) => {}
                    Err(e) if e.kind() == ErrorKind::WouldBlock => {
                        self.overflows.fetch_add(1, Ordering::SeqCst);
                        tracing::warn!(hub = %self.interface, node = other, "receive queue full: frame lost");
                    }
                    // A departed node: its own thread removes it.
                    Err(_) => {}
                }
            }
        }
        self.remove_client(id);
    }

    fn remove_client(&self, id: u64) {
        let mut clients = self.lock_clients();
        clients.list.retain(|(other, _)| *other != id);
        if self.exit_when_empty && clients.list.is_empty() && !self.stop.load(Ordering::SeqCst) {
            drop(clients);
            tracing::debug!(hub = %self.interface, "last node left; hub exits");
            self.shut_down();
        }
    }

    fn shut_down(&self) {
        let clients = {
            let mut clients = self.lock_clients();
            self.stop.store(true, Ordering::SeqCst);
            std::mem::take(&mut clients.list)
        };
        let _ = self.listener.shutdown(std::net::Shutdown::Both);
        for (_, socket) in clients {
            let _ = socket.shutdown(std::net::Shutdown::Both);
        }
        // Remove the file only if it is still ours (not a successor hub's).
        if let Ok(meta) = std::fs::metadata(&self.path) {
            if (meta.dev(), meta.ino()) == self.identity {
                let _ = std::fs::remove_file(&self.path);
            }
        }
    }
}

/// A node on a cross-process virtual bus.
pub struct UnixBus {
    socket: Socket,
    interface: String,
    state: BusState,
}

/// Why a connection attempt failed.
enum ConnectError {
    /// No live hub (no file, stale file, or it closed on us): start one and retry.
    NoHub(std::io::Error),
    /// Anything else.
    Other(CanError),
}

impl UnixBus {
    /// Connects to the running hub of virtual bus `name`.
    pub fn connect(name: &str) -> Result<UnixBus, CanError> {
        let interface = interface_of(name);
        Self::try_connect(name).map_err(|e| match e {
            ConnectError::NoHub(source) => CanError::Open {
                interface,
                error: source,
            },
            ConnectError::Other(e) => e,
        })
    }

    /// Connects to virtual bus `name`, first starting its hub on a thread of this
    /// process when none runs. That hub serves until its last node disconnects,
    /// and no longer than this process lives.
    pub fn open(name: &str) -> Result<UnixBus, CanError> {
        let mut last = None;
        for _ in 0..5 {
            match Self::try_connect(name) {
                Ok(bus) => return Ok(bus),
                Err(ConnectError::Other(e)) => return Err(e),
                Err(ConnectError::NoHub(e)) => last = Some(e),
            }
            match Hub::start(name, true, None) {
                Ok(hub) => hub.detach(),
                // Another process won the race: connect to its hub.
                Err(CanError::Open { error: source, .. })
                    if source.kind() == ErrorKind::AddrInUse => {}
                Err(e) => return Err(e),
            }
        }
        Err(CanError::Open {
            interface: interface_of(name),
            error: last.unwrap_or_else(|| ErrorKind::NotConnected.into()),
        })
    }

    fn try_connect(name: &str) -> Result<UnixBus, ConnectError> {
        let interface = interface_of(name);
        let path = prepare_path(name).map_err(ConnectError::Other)?;
        let other = |source| {
            ConnectError::Other(CanError::Open {
                interface: interface.clone(),
                error: source,
            })
        };
        let socket = new_seqpacket_socket().map_err(other)?;
        let address = SockAddr::unix(&path).map_err(other)?;
        if let Err(e) = socket.connect(&address) {
            return Err(match e.kind() {
                ErrorKind::NotFound | ErrorKind::ConnectionRefused => ConnectError::NoHub(e),
                _ => other(e),
            });
        }
        socket
            .set_read_timeout(Some(GREETING_TIMEOUT))
            .map_err(other)?;
        socket
            .set_write_timeout(Some(SEND_TIMEOUT))
            .map_err(other)?;
        let mut buf = [0u8; 64];
        match recv_packet(&socket, &mut buf, 0) {
            Ok(n) if &buf[..n] == GREETING => {}
            // Closed at once: a hub that was exiting. Start over.
            Ok(0) => return Err(ConnectError::NoHub(ErrorKind::ConnectionReset.into())),
            Ok(n) => {
                return Err(ConnectError::Other(CanError::BadPacket {
                    interface,
                    len: n,
                    problem: PacketError::NotGreeting,
                }))
            }
            Err(e) if e.kind() == ErrorKind::ConnectionReset => return Err(ConnectError::NoHub(e)),
            Err(e) => return Err(other(e)),
        }
        Ok(UnixBus {
            socket,
            interface,
            state: BusState::ErrorActive,
        })
    }

    fn disconnected(&mut self, reason: String) -> CanError {
        self.state = BusState::Disconnected;
        CanError::Disconnected {
            interface: self.interface.clone(),
            reason,
        }
    }
}

impl CanBus for UnixBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        if self.state == BusState::Disconnected {
            return Err(self.disconnected("hub gone".into()));
        }
        loop {
            return match self
                .socket
                .send_with_flags(&encode_packet(frame), libc::MSG_NOSIGNAL)
            {
                Ok(_) => Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    Err(CanError::SendTimeout {
                        interface: self.interface.clone(),
                        frame: *frame,
                        timeout_s: SEND_TIMEOUT.as_secs_f64(),
                    })
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::BrokenPipe
                            | ErrorKind::ConnectionReset
                            | ErrorKind::NotConnected
                    ) =>
                {
                    Err(self.disconnected(e.to_string()))
                }
                Err(source) => Err(CanError::Io {
                    interface: self.interface.clone(),
                    operation: "send",
                    error: source,
                }),
            };
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, CanError> {
        if self.state == BusState::Disconnected {
            return Err(self.disconnected("hub gone".into()));
        }
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 64];
        loop {
            let remaining = deadline.saturating_duration_since(Instant::now());
            let received = if remaining.is_zero() {
                recv_packet(&self.socket, &mut buf, libc::MSG_DONTWAIT)
            } else {
                self.socket
                    .set_read_timeout(Some(remaining))
                    .and_then(|()| recv_packet(&self.socket, &mut buf, 0))
            };
            return match received {
                Ok(0) => Err(self.disconnected("the hub closed the connection".into())),
                Ok(n) => {
                    decode_packet(&buf[..n])
                        .map(Some)
                        .map_err(|problem| CanError::BadPacket {
                            interface: self.interface.clone(),
                            len: n,
                            problem,
                        })
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    Ok(None)
                }
                Err(e) if e.kind() == ErrorKind::ConnectionReset => {
                    Err(self.disconnected(e.to_string()))
                }
                Err(source) => Err(CanError::Io {
                    interface: self.interface.clone(),
                    operation: "receive",
                    error: source,
                }),
            };
        }
    }

    fn state(&self) -> BusState {
        self.state
    }

    fn interface(&self) -> &str {
        &self.interface
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unique(tag: &str) -> String {
        static COUNTER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        format!(
            "unit-{tag}-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::SeqCst)
        )
    }

    #[test]
    fn packet_is_can_frame_layout_and_garbage_is_named() {
        let frame = CanFrame::new(0x566, &[0xB0, 0, 1, 2, 3, 4]).unwrap();
        let packet = encode_packet(&frame);
        assert_eq!(
            packet,
            [0x66, 0x05, 0, 0, 6, 0, 0, 0, 0xB0, 0, 1, 2, 3, 4, 0, 0]
        );
        assert_eq!(decode_packet(&packet).unwrap(), frame);
        let text = |bytes: &[u8]| decode_packet(bytes).unwrap_err().to_string();
        assert!(text(&packet[..15]).contains("16 bytes"));
        let mut extended = packet;
        extended[3] = 0x80;
        assert!(text(&extended).contains("0x80000566"));
        let mut long = packet;
        long[4] = 9;
        assert!(text(&long).contains("DLC 9"));
    }

    #[test]
    fn stale_socket_file_is_replaced_and_live_hub_is_not() {
        let name = unique("stale");
        let path = prepare_path(&name).unwrap();
        // A socket file nobody listens on: bound, then its socket closed.
        {
            let dead = new_seqpacket_socket().unwrap();
            dead.bind(&SockAddr::unix(&path).unwrap()).unwrap();
        }
        assert!(path.exists());
        let hub = Hub::bind(&name).unwrap();
        let err = Hub::bind(&name).err().unwrap().to_string();
        assert!(
            err.contains(&name) && err.contains("already serves"),
            "{err}"
        );
        let mut a = UnixBus::connect(&name).unwrap();
        let mut b = UnixBus::connect(&name).unwrap();
        let frame = CanFrame::new(0x123, &[1, 2, 3]).unwrap();
        a.send(&frame).unwrap();
        assert_eq!(b.recv(Duration::from_secs(5)).unwrap(), Some(frame));
        drop(hub);
        assert!(!path.exists());
        let err = b.recv(Duration::from_secs(5)).unwrap_err();
        assert!(matches!(err, CanError::Disconnected { .. }), "{err}");
        assert_eq!(b.state(), BusState::Disconnected);
    }

    #[test]
    fn hub_with_faults_loses_frames_reproducibly() {
        let run = |seed| {
            let name = unique("faults");
            let hub = Hub::bind_with_faults(
                &name,
                FaultConfig {
                    loss_probability: 0.25,
                    seed,
                    ..FaultConfig::default()
                },
            )
            .unwrap();
            let hub = std::sync::Arc::new(hub);
            let mut a = UnixBus::connect(&name).unwrap();
            let mut b = UnixBus::connect(&name).unwrap();
            // Read while sending until every frame is accounted for: received, lost by
            // injection, or lost to a full receive queue (a reader starved of CPU
            // overflows, as a CAN controller does). No timing decides what the test
            // sees, however loaded the machine.
            let counter = std::sync::Arc::clone(&hub);
            let reader = std::thread::spawn(move || {
                let mut got = Vec::new();
                let deadline = std::time::Instant::now() + Duration::from_secs(60);
                loop {
                    let c = counter.fault_counts();
                    let accounted = got.len() as u64 + c.lost + counter.overflows();
                    if c.sent == 400 && accounted >= 400 {
                        break;
                    }
                    assert!(
                        std::time::Instant::now() < deadline,
                        "{c:?}, {} read",
                        got.len()
                    );
                    if let Some(f) = b.recv(Duration::from_millis(50)).unwrap() {
                        got.push(u16::from_le_bytes([f.data()[0], f.data()[1]]));
                    }
                }
                got
            });
            for i in 0..400u16 {
                a.send(&CanFrame::new(0x100, &i.to_le_bytes()).unwrap())
                    .unwrap();
            }
            let got = reader.join().unwrap();
            let counts = hub.fault_counts();
            assert_eq!(counts.sent, 400);
            let overflows = hub.overflows() as usize;
            assert_eq!(counts.lost as usize + overflows, 400 - got.len());
            (got, overflows)
        };
        let (first, overflows) = run(3);
        // Binomial(400, 0.75): mean 300, sd 8.7; +-5 sd.
        assert!(
            (257..=343).contains(&(first.len() + overflows)),
            "{}",
            first.len()
        );
        assert!(first.windows(2).all(|w| w[0] < w[1]), "order kept");
        // The same seed loses the same frames (overflows aside, which depend on load).
        let (second, more_overflows) = run(3);
        if overflows == 0 && more_overflows == 0 {
            assert_eq!(first, second);
        } else {
            let mut lost = (0..400u16).filter(|i| !first.contains(i) && second.contains(i));
            assert!(lost.nth(overflows + more_overflows).is_none());
        }
        let err = Hub::bind_with_faults(
            &unique("latency"),
            FaultConfig {
                latency: Duration::from_millis(1),
                ..FaultConfig::default()
            },
        )
        .err()
        .unwrap()
        .to_string();
        assert!(err.contains("latency"), "{err}");
    }

    #[test]
    fn a_hubs_faults_change_at_run_time_and_only_with_injection() {
        let name = unique("set-faults");
        let hub = Hub::bind_with_faults(&name, FaultConfig::default()).unwrap();
        let mut a = UnixBus::connect(&name).unwrap();
        let mut b = UnixBus::connect(&name).unwrap();
        let frame = CanFrame::new(0x123, &[1]).unwrap();
        a.send(&frame).unwrap();
        assert_eq!(b.recv(Duration::from_secs(5)).unwrap(), Some(frame));
        let lose_all = FaultConfig {
            loss_probability: 1.0,
            ..FaultConfig::default()
        };
        hub.set_faults(&lose_all).unwrap();
        a.send(&frame).unwrap();
        assert_eq!(b.recv(Duration::from_millis(200)).unwrap(), None);
        assert_eq!(hub.fault_counts().lost, 1);
        hub.set_faults(&FaultConfig::default()).unwrap();
        a.send(&frame).unwrap();
        assert_eq!(b.recv(Duration::from_secs(5)).unwrap(), Some(frame));
        let bad = FaultConfig {
            corrupt_probability: 2.0,
            ..FaultConfig::default()
        };
        assert!(hub.set_faults(&bad).is_err());
        let plain = Hub::bind(&unique("no-faults")).unwrap();
        let err = plain.set_faults(&lose_all).unwrap_err().to_string();
        assert!(err.contains("without fault injection"), "{err}");
    }

    #[test]
    fn open_hosts_a_hub_that_leaves_with_its_last_node() {
        let name = unique("auto");
        let err = UnixBus::connect(&name).err().unwrap().to_string();
        assert!(err.contains(&format!("virtual:{name}")), "{err}");
        let a = UnixBus::open(&name).unwrap();
        let b = UnixBus::open(&name).unwrap();
        assert!(hub_socket_path(&name).exists());
        drop(a);
        drop(b);
        // The hub removes its file once its last node has gone.
        let start = Instant::now();
        while hub_socket_path(&name).exists() && start.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(5));
        }
        assert!(!hub_socket_path(&name).exists());
        // And a later open starts a fresh hub.
        let _c = UnixBus::open(&name).unwrap();
    }
}
