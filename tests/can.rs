//! CAN: one conformance suite run on every bus backend, the BH8-282 driver against
//! the puck emulator (in-process, cross-process, as a child process), and
//! frame-exact checks of the protocol.

use graspcell::clock::{Clock, ManualClock, SystemClock};
use graspcell::fsio::TempDir;
use graspcell::hw::can::CanFrame;
use graspcell::hw::can::{
    open_bus, BusState, CanBus, CanError, CandumpBus, Corruption, FaultConfig, Hub, SocketCanBus,
    UnixBus, VirtualBus,
};
use graspcell::hw::hand::puck::{group_id, Property};
use graspcell::hw::hand::{Hand, HandError, HandPositions, HandTiming, MotionOutcome, Puck};
use graspcell::sim::puck::{EmulatorThread, HandEmulator, HandEmulatorConfig};
use std::io::{BufRead, BufReader};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Long enough for any frame that should arrive (never asserted as a maximum).
const ARRIVES: Duration = Duration::from_secs(5);
/// How long to listen for a frame that must not arrive.
const QUIET: Duration = Duration::from_millis(50);
/// Budget of one hand call on the test's manual clock (virtual seconds).
const CALL: Duration = Duration::from_secs(30);

/// A bus name no other test (or parallel test run) uses.
fn unique(tag: &str) -> String {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    format!(
        "t-{tag}-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::SeqCst)
    )
}

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(id, data).unwrap()
}

// ---------------------------------------------------------------------------
// The conformance suite: generic over a factory that attaches a node to one bus.
// ---------------------------------------------------------------------------

type Node = Box<dyn CanBus>;

/// Runs every conformance check on the bus `node` attaches to.
fn conformance(backend: &str, mut node: impl FnMut() -> Node) {
    broadcast_without_loopback(backend, &mut node);
    frames_arrive_bit_exact(backend, &mut node);
    order_is_kept(backend, &mut node);
    senders_interleave(backend, &mut node);
    empty_bus_times_out(backend, &mut node);
    hand_driver_runs(backend, &mut node);
}

fn broadcast_without_loopback(backend: &str, node: &mut impl FnMut() -> Node) {
    let (mut a, mut b, mut c) = (node(), node(), node());
    for n in [&a, &b, &c] {
        assert_eq!(n.state(), BusState::ErrorActive, "{backend}");
    }
    let f1 = frame(0x405, &[0x9D, 0x00, 0x12, 0x00, 0x00, 0x00]);
    a.send(&f1).unwrap();
    assert_eq!(b.recv(ARRIVES).unwrap(), Some(f1), "{backend}: b");
    assert_eq!(c.recv(ARRIVES).unwrap(), Some(f1), "{backend}: c");
    let f2 = frame(0x566, &[0x81, 0x00, 0x05, 0x08]);
    c.send(&f2).unwrap();
    assert_eq!(a.recv(ARRIVES).unwrap(), Some(f2), "{backend}: a");
    assert_eq!(b.recv(ARRIVES).unwrap(), Some(f2), "{backend}: b");
    // No loopback: senders never hear themselves.
    assert_eq!(a.recv(QUIET).unwrap(), None, "{backend}: a heard itself");
    assert_eq!(c.recv(QUIET).unwrap(), None, "{backend}: c heard itself");
}

fn frames_arrive_bit_exact(backend: &str, node: &mut impl FnMut() -> Node) {
    let (mut a, mut b) = (node(), node());
    let mut sent = Vec::new();
    for len in 0..=8usize {
        for id in [0x000, 0x00B, 0x405, 0x7FF] {
            let data: Vec<u8> = (0..len).map(|i| (0xA5 ^ (i * 37 + id)) as u8).collect();
            sent.push(frame(id as u16, &data));
        }
    }
    for f in &sent {
        a.send(f).unwrap();
    }
    for (i, f) in sent.iter().enumerate() {
        assert_eq!(
            b.recv(ARRIVES).unwrap().as_ref(),
            Some(f),
            "{backend}: frame {i}"
        );
    }
}

fn order_is_kept(backend: &str, node: &mut impl FnMut() -> Node) {
    let (mut a, mut b) = (node(), node());
    let count = 100u16;
    let reader = std::thread::spawn(move || {
        (0..count)
            .map(|_| b.recv(ARRIVES).unwrap())
            .collect::<Vec<_>>()
    });
    for i in 0..count {
        a.send(&frame(0x100, &i.to_le_bytes())).unwrap();
    }
    let got = reader.join().unwrap();
    let expected: Vec<_> = (0..count)
        .map(|i| Some(frame(0x100, &i.to_le_bytes())))
        .collect();
    assert_eq!(got, expected, "{backend}");
}

fn senders_interleave(backend: &str, node: &mut impl FnMut() -> Node) {
    let (mut a, mut b, mut c) = (node(), node(), node());
    for i in 0..20u8 {
        a.send(&frame(0x0A, &[i])).unwrap();
        b.send(&frame(0x0B, &[i])).unwrap();
    }
    let mut from = [Vec::new(), Vec::new()];
    for _ in 0..40 {
        let f = c.recv(ARRIVES).unwrap().expect("frame");
        from[usize::from(f.id() == 0x0B)].push(f.data()[0]);
    }
    let each: Vec<u8> = (0..20).collect();
    assert_eq!(from, [each.clone(), each], "{backend}");
}

fn empty_bus_times_out(backend: &str, node: &mut impl FnMut() -> Node) {
    let mut a = node();
    let _b = node();
    assert_eq!(a.recv(Duration::ZERO).unwrap(), None, "{backend}");
    assert_eq!(a.recv(QUIET).unwrap(), None, "{backend}");
}

/// The driver's bring-up, a grasp and an opening, against the emulator on this bus.
/// Both run on the real clock (a virtual clock cannot be shared across processes),
/// with a short wake settle to keep it brief.
fn hand_driver_runs(backend: &str, node: &mut impl FnMut() -> Node) {
    let contact = [1.0, 1.2, 0.9];
    let mut rig = Rig::new(
        node(),
        node(),
        HandEmulatorConfig {
            contact_rad: [Some(contact[0]), Some(contact[1]), Some(contact[2]), None],
            boot: Duration::from_millis(100),
            ..HandEmulatorConfig::default()
        },
        HandTiming {
            wake_settle: Duration::from_millis(300),
            ..HandTiming::default()
        },
        Arc::new(SystemClock::new()),
    );
    let call = Duration::from_secs(20);
    rig.hand.wake(call).unwrap();
    rig.hand.identify(call).unwrap();
    rig.hand.initialise(call).unwrap();
    let closed = rig.hand.close(call).unwrap();
    assert_stalled_at(&closed, contact, backend);
    let opened = rig.hand.open(call).unwrap();
    assert!(
        opened
            .iter()
            .all(|o| o.reached_target && o.position_rad.abs() < 1e-4),
        "{backend}: {opened:?}"
    );
}

fn assert_stalled_at(outcomes: &[MotionOutcome], contact_rad: [f64; 3], context: &str) {
    assert_eq!(outcomes.len(), 3, "{context}: {outcomes:?}");
    for (o, want) in outcomes.iter().zip(contact_rad) {
        assert!(!o.reached_target, "{context}: {o:?}");
        // One count is 1.2e-5 rad.
        assert!(
            (o.position_rad - want).abs() < 1e-4,
            "{context}: {o:?} vs {want}"
        );
    }
}

#[test]
fn conformance_in_process() {
    let bus = VirtualBus::new(&unique("inproc"));
    conformance("in-process", || Box::new(bus.endpoint()));
}

#[test]
fn conformance_in_process_with_candump_logging() {
    let dir = TempDir::new("can-candump-conf").unwrap();
    let bus = VirtualBus::new(&unique("inproc-log"));
    let mut n = 0;
    conformance("in-process+candump", || {
        n += 1;
        Box::new(CandumpBus::create(bus.endpoint(), &dir.join(format!("{n}.log"))).unwrap())
    });
}

#[test]
fn conformance_cross_process_hub_thread() {
    let name = unique("hub");
    let hub = Hub::bind(&name).unwrap();
    conformance("cross-process (hub thread)", || {
        Box::new(UnixBus::connect(&name).unwrap())
    });
    drop(hub);
}

#[test]
fn conformance_cross_process_open_bus() {
    let interface = format!("virtual:{}", unique("auto"));
    // Keep one node so the auto-started hub outlives the suite's nodes.
    let _anchor = open_bus(&interface).unwrap();
    conformance("cross-process (virtual:NAME)", || {
        open_bus(&interface).unwrap()
    });
}

/// The suite on the kernel's vcan0. This kernel has no CAN at all (creating an
/// AF_CAN socket fails), so by default the test is reported as ignored with the
/// reason; `--features vcan_tests` runs it, and then a missing vcan0 is a failure.
#[test]
#[cfg_attr(
    not(feature = "vcan_tests"),
    ignore = "SKIPPED: needs vcan0 (kernel SocketCAN); run with --features vcan_tests where `ip link add vcan0 type vcan` works"
)]
fn conformance_socketcan_vcan0() {
    if let Err(e) = SocketCanBus::open("vcan0") {
        panic!("vcan_tests enabled but vcan0 cannot be opened: {e}");
    }
    conformance("socketcan vcan0", || {
        Box::new(SocketCanBus::open("vcan0").unwrap())
    });
}

#[test]
fn socketcan_open_failure_names_interface_and_os_error() {
    // Whatever the kernel, no interface has this name.
    let err = open_bus("gcnone0").err().unwrap();
    let text = err.to_string();
    assert!(matches!(err, CanError::Open { .. }), "{text}");
    assert!(
        text.contains("`gcnone0`") && text.contains("os error"),
        "{text}"
    );
}

// ---------------------------------------------------------------------------
// The driver against the emulator.
// ---------------------------------------------------------------------------

/// A driver and an emulator on one bus, sharing a clock.
struct Rig {
    hand: Hand<Node>,
    emulator: Option<EmulatorThread>,
}

impl Rig {
    fn new(
        emulator_node: Node,
        driver_node: Node,
        config: HandEmulatorConfig,
        timing: HandTiming,
        clock: Arc<dyn Clock>,
    ) -> Rig {
        let emulator = HandEmulator::new(config, Arc::clone(&clock))
            .unwrap()
            .spawn(emulator_node);
        Rig {
            hand: Hand::new(driver_node, clock, timing),
            emulator: Some(emulator),
        }
    }

    /// On an in-process bus with a manual clock in lockstep: the driver's sleeps
    /// advance virtual time only once the emulator has handled what was sent.
    fn on_virtual_bus(bus: &VirtualBus, config: HandEmulatorConfig, timing: HandTiming) -> Rig {
        let emulator_node = bus.endpoint();
        let probe = emulator_node.idle_probe();
        let clock = ManualClock::new().with_settle(move || {
            probe.wait_idle(ARRIVES);
        });
        Rig::new(
            Box::new(emulator_node),
            Box::new(bus.endpoint()),
            config,
            timing,
            Arc::new(clock),
        )
    }

    fn bring_up(&mut self) {
        self.hand.wake(CALL).unwrap();
        self.hand.identify(CALL).unwrap();
        self.hand.initialise(CALL).unwrap();
    }

    fn emulator(&mut self) -> HandEmulator {
        self.emulator.take().unwrap().stop().unwrap().0
    }
}

#[test]
fn bring_up_reports_what_the_pucks_are() {
    let bus = VirtualBus::new(&unique("identify"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.hand.wake(CALL).unwrap();
    let info = rig.hand.identify(CALL).unwrap();
    for (i, puck) in Puck::ALL.into_iter().enumerate() {
        assert_eq!(info[i].puck, puck);
        assert_eq!(info[i].role & 0x1F, 5);
        assert_eq!(info[i].counts_per_rev, 4096);
        assert_eq!(info[i].has_strain_gauge, puck.is_finger());
        let ratio = if puck.is_finger() { 125.0 } else { 17.5 };
        let expected = 4096.0 / (2.0 * std::f64::consts::PI) * ratio;
        assert!((info[i].counts_per_rad - expected).abs() < 1e-9);
    }
    let homed = rig.hand.initialise(CALL).unwrap();
    assert!(
        homed
            .iter()
            .all(|o| o.reached_target && o.position_rad == 0.0),
        "{homed:?}"
    );
    // The emulator started off zero (4000, -3000, 2500, 1200 counts): HI moved it.
    let mut emulator = rig.emulator();
    for puck in Puck::ALL {
        assert_eq!(emulator.position_counts(puck), Some(0));
    }
}

#[test]
fn grasp_stalls_on_the_object_with_strain_then_opens() {
    let contact = [0.8, 1.1, 1.4];
    let bus = VirtualBus::new(&unique("grasp"));
    let mut rig = Rig::on_virtual_bus(
        &bus,
        HandEmulatorConfig {
            contact_rad: [Some(contact[0]), Some(contact[1]), Some(contact[2]), None],
            ..HandEmulatorConfig::default()
        },
        HandTiming::default(),
    );
    rig.bring_up();
    assert_eq!(rig.hand.strain(CALL).unwrap(), [2000; 3]);
    let closed = rig.hand.close(CALL).unwrap();
    assert_stalled_at(&closed, contact, "close");
    let strain = rig.hand.strain(CALL).unwrap();
    assert!(strain.iter().all(|&sg| sg > 2500), "{strain:?}");
    let p = rig.hand.positions(CALL).unwrap();
    for (got, want) in p.fingers_rad.iter().zip(contact) {
        assert!((got - want).abs() < 1e-4, "{p:?}");
    }
    rig.hand.stop(CALL).unwrap();
    let mut emulator_modes = Vec::new();
    for puck in Puck::ALL {
        emulator_modes.push(rig.hand.get_property(puck, Property::Mode, CALL).unwrap());
    }
    assert_eq!(emulator_modes, [3, 3, 3, 3]);
    let opened = rig.hand.open(CALL).unwrap();
    assert!(opened.iter().all(|o| o.reached_target), "{opened:?}");
    assert_eq!(rig.hand.strain(CALL).unwrap(), [2000; 3]);
}

#[test]
fn fingers_and_spread_move_to_positions() {
    let bus = VirtualBus::new(&unique("move"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.bring_up();
    let target = HandPositions {
        fingers_rad: [0.5, 1.0, 1.5],
        spread_rad: 1.2,
    };
    let outcomes = rig.hand.move_to(&target, CALL).unwrap();
    assert!(outcomes.iter().all(|o| o.reached_target), "{outcomes:?}");
    let p = rig.hand.positions(CALL).unwrap();
    for i in 0..3 {
        assert!(
            (p.fingers_rad[i] - target.fingers_rad[i]).abs() < 1e-4,
            "{p:?}"
        );
    }
    assert!((p.spread_rad - 1.2).abs() < 1e-4, "{p:?}");
    // The spread holds (HOLD = 1, MODE 3), the fingers idle (HOLD = 0, MODE 0).
    assert_eq!(
        rig.hand
            .get_property(Puck::Spread, Property::Mode, CALL)
            .unwrap(),
        3
    );
    assert_eq!(
        rig.hand
            .get_property(Puck::F1, Property::Mode, CALL)
            .unwrap(),
        0
    );

    let bad = HandPositions {
        fingers_rad: [0.5, f64::NAN, 1.5],
        spread_rad: 1.2,
    };
    let err = rig.hand.move_to(&bad, CALL).unwrap_err();
    assert!(
        matches!(err, HandError::OutOfRange { puck: Puck::F2, .. }),
        "{err}"
    );
    let too_far = HandPositions {
        fingers_rad: [0.5, 1.0, 1.5],
        spread_rad: 3.5,
    };
    let err = rig.hand.move_to(&too_far, CALL).unwrap_err().to_string();
    assert!(
        err.contains("spread (node 14)") && err.contains("3.5"),
        "{err}"
    );
}

#[test]
fn wrong_role_and_old_firmware_are_refused() {
    let bus = VirtualBus::new(&unique("role"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.hand.wake(CALL).unwrap();
    // F2 claims role 4 (not a hand puck).
    bus.endpoint()
        .send(&frame(12, &[0x80 | 1, 0x00, 4, 0, 0, 0]))
        .unwrap();
    let err = rig.hand.identify(CALL).unwrap_err();
    assert!(
        matches!(
            err,
            HandError::WrongRole {
                puck: Puck::F2,
                role: 4
            }
        ),
        "{err}"
    );

    let bus = VirtualBus::new(&unique("firmware"));
    let mut rig = Rig::on_virtual_bus(
        &bus,
        HandEmulatorConfig {
            firmware_version: 131,
            ..HandEmulatorConfig::default()
        },
        HandTiming::default(),
    );
    rig.hand.wake(CALL).unwrap();
    let err = rig.hand.identify(CALL).unwrap_err().to_string();
    assert!(err.contains("F1 (node 11)") && err.contains("131"), "{err}");
}

#[test]
fn motion_before_initialise_is_refused() {
    let bus = VirtualBus::new(&unique("order"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    let err = rig.hand.close(CALL).unwrap_err().to_string();
    assert!(err.contains("identify"), "{err}");
    rig.hand.wake(CALL).unwrap();
    rig.hand.identify(CALL).unwrap();
    let err = rig.hand.close(CALL).unwrap_err().to_string();
    assert!(err.contains("initialise"), "{err}");
}

#[test]
fn five_percent_frame_loss_is_retried() {
    // Seeds are reported in the failure message; each run is reproducible up to
    // thread scheduling (a reply later than the reply timeout).
    let mut completed = 0;
    for seed in 1..=3u64 {
        let bus = VirtualBus::with_faults(
            &unique("loss"),
            FaultConfig {
                loss_probability: 0.05,
                seed,
                ..FaultConfig::default()
            },
        )
        .unwrap();
        let contact = [1.0, 1.0, 1.0];
        let mut rig = Rig::on_virtual_bus(
            &bus,
            HandEmulatorConfig {
                contact_rad: [Some(1.0), Some(1.0), Some(1.0), None],
                ..HandEmulatorConfig::default()
            },
            HandTiming {
                reply_timeout: Duration::from_millis(30),
                ..HandTiming::default()
            },
        );
        let result = (|| -> Result<Vec<MotionOutcome>, HandError> {
            rig.hand.wake(CALL)?;
            rig.hand.identify(CALL)?;
            rig.hand.initialise(CALL)?;
            let closed = rig.hand.close(CALL)?;
            let grasped = rig.hand.positions(CALL)?;
            for (got, want) in grasped.fingers_rad.iter().zip(contact) {
                assert!((got - want).abs() < 1e-4, "seed {seed}: {grasped:?}");
            }
            rig.hand.open(CALL)?;
            Ok(closed)
        })();
        let counts = bus.fault_counts();
        assert!(
            counts.lost > 0,
            "seed {seed}: no frame was lost: {counts:?}"
        );
        match result {
            Ok(closed) => {
                assert_stalled_at(&closed, contact, &format!("seed {seed}"));
                eprintln!("seed {seed}: completed despite {counts:?}");
                completed += 1;
            }
            // Failing cleanly: a named error, never a wrong answer.
            Err(
                e @ (HandError::NoReply { .. }
                | HandError::CommandIgnored { .. }
                | HandError::SetNotApplied { .. }
                | HandError::NotReady { .. }),
            ) => {
                eprintln!("seed {seed}: failed cleanly after {counts:?}: {e}");
            }
            Err(e) => panic!("seed {seed}: unclean failure after {counts:?}: {e}"),
        }
    }
    assert!(completed >= 1, "no run completed under 5 % loss");
}

#[test]
fn silent_puck_times_out_naming_it() {
    let bus = VirtualBus::new(&unique("silent"));
    let mut rig = Rig::on_virtual_bus(
        &bus,
        HandEmulatorConfig {
            present: [true, true, false, true],
            ..HandEmulatorConfig::default()
        },
        HandTiming::default(),
    );
    let err = rig.hand.wake(CALL).unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(
            &err,
            HandError::NoReply {
                puck: Puck::F3,
                attempts: 5,
                ..
            }
        ),
        "{text}"
    );
    assert!(
        text.contains("F3 (node 13)") && text.contains("get STAT"),
        "{text}"
    );
}

#[test]
fn garbled_reply_is_reported_with_the_frame() {
    // Every reply from F1 (0x560..=0x57F) loses part of its data.
    let bus = VirtualBus::with_faults(
        &unique("garbled"),
        FaultConfig {
            corrupt_probability: 1.0,
            corruption: Corruption::Truncate,
            affected_ids: Some(0x560..=0x57F),
            seed: 11,
            ..FaultConfig::default()
        },
    )
    .unwrap();
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    let err = rig.hand.wake(CALL).unwrap_err();
    let text = err.to_string();
    let HandError::Garbled { puck, frame, .. } = &err else {
        panic!("not a garbled-frame error: {text}");
    };
    assert_eq!(*puck, Puck::F1);
    assert_eq!(frame.id(), 0x566);
    // STAT's reply has 4 bytes; the truncated one fewer.
    assert!(frame.len() < 4, "{text}");
    assert!(text.contains("566#") && text.contains("get STAT"), "{text}");
}

#[test]
fn bus_off_is_reported_by_the_driver() {
    let bus = VirtualBus::new(&unique("busoff"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.hand.wake(CALL).unwrap();
    bus.set_bus_off(true);
    let err = rig.hand.identify(CALL).unwrap_err();
    assert!(
        matches!(err, HandError::Bus(CanError::BusOff { .. })),
        "{err}"
    );
}

// ---------------------------------------------------------------------------
// Frame-exact checks.
// ---------------------------------------------------------------------------

/// Every frame a silent listener heard.
fn drain(node: &mut impl CanBus) -> Vec<CanFrame> {
    std::iter::from_fn(|| node.recv(QUIET).unwrap()).collect()
}

#[test]
fn close_sets_tstop_then_sends_cmd_c_to_each_finger() {
    let bus = VirtualBus::new(&unique("close-frames"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.bring_up();
    let mut sniffer = bus.endpoint();
    rig.hand.close(CALL).unwrap();
    let heard = drain(&mut sniffer);
    let cmd_c = [0x80 | 29, 0x00, 18, 0, 0, 0];
    let tstop_50 = [0x80 | 78, 0x00, 50, 0, 0, 0];
    for finger in Puck::FINGERS {
        let id = u16::from(finger.node());
        let first_c = heard
            .iter()
            .position(|f| f.id() == id && f.data() == cmd_c)
            .unwrap_or_else(|| panic!("no CMD = C to {finger}: {heard:?}"));
        let first_tstop = heard
            .iter()
            .position(|f| f.id() == id && f.data() == tstop_50)
            .unwrap_or_else(|| panic!("no TSTOP = 50 to {finger}: {heard:?}"));
        assert!(first_tstop < first_c, "{finger}: TSTOP after C");
    }
    // The spread is not part of a grasp closing.
    assert!(!heard.iter().any(|f| f.id() == 14 && f.data() == cmd_c));
    assert!(!heard.iter().any(|f| f.id() == 0x405 && f.data() == cmd_c));
}

#[test]
fn wake_sends_stat_2_to_each_puck_in_order() {
    let bus = VirtualBus::new(&unique("wake-frames"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    let mut sniffer = bus.endpoint();
    rig.hand.wake(CALL).unwrap();
    let heard = drain(&mut sniffer);
    let sets: Vec<String> = heard[..4].iter().map(|f| f.to_string()).collect();
    assert_eq!(
        sets,
        [
            "00B#850002000000",
            "00C#850002000000",
            "00D#850002000000",
            "00E#850002000000"
        ]
    );
    // Then STAT is read back: get [5] to each puck, answered on group 6.
    assert_eq!(heard[4], frame(11, &[5]));
    assert_eq!(heard[5], frame(0x566, &[0x85, 0x00, 0x02, 0x00]));
}

#[test]
fn stop_sends_mode_3_to_the_hand_group() {
    let bus = VirtualBus::new(&unique("stop-frames"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.bring_up();
    let mut sniffer = bus.endpoint();
    rig.hand.stop(CALL).unwrap();
    let heard = drain(&mut sniffer);
    assert_eq!(heard[0], frame(0x405, &[0x80 | 8, 0x00, 3, 0, 0, 0]));
}

/// A scripted puck: answers each request with what `script` returns, `requests`
/// times, and hands back the requests it saw.
fn scripted_peer(
    mut node: impl CanBus + 'static,
    requests: usize,
    script: impl Fn(usize, &CanFrame) -> Vec<CanFrame> + Send + 'static,
) -> std::thread::JoinHandle<Vec<CanFrame>> {
    std::thread::spawn(move || {
        let mut seen = Vec::new();
        while seen.len() < requests {
            let Some(request) = node.recv(ARRIVES).unwrap() else {
                break;
            };
            for reply in script(seen.len(), &request) {
                node.send(&reply).unwrap();
            }
            seen.push(request);
        }
        seen
    })
}

#[test]
fn reading_p_from_f1_is_byte_exact_in_both_reply_formats() {
    let bus = VirtualBus::new(&unique("p-frames"));
    // First a property reply on group 6: F1 (node 11) -> 0x400 | 11 << 5 | 6 =
    // 0x566, P = -5000 = 0xFFFFEC78 little-endian. Then a 22-bit position reply on
    // group 3 (0x563): -1000 = 0x3FFC18 -> [0x80 | 0x3F, 0xFC, 0x18].
    let peer = scripted_peer(bus.endpoint(), 2, |i, _| {
        vec![if i == 0 {
            CanFrame::new(0x566, &[0xB0, 0x00, 0x78, 0xEC, 0xFF, 0xFF]).unwrap()
        } else {
            CanFrame::new(0x563, &[0xBF, 0xFC, 0x18]).unwrap()
        }]
    });
    let mut hand = Hand::new(
        bus.endpoint(),
        Arc::new(ManualClock::new()),
        HandTiming::default(),
    );
    assert_eq!(hand.position_counts(Puck::F1, CALL).unwrap(), -5000);
    assert_eq!(hand.position_counts(Puck::F1, CALL).unwrap(), -1000);
    let requests = peer.join().unwrap();
    assert_eq!(requests, [frame(11, &[48]), frame(11, &[48])]);
}

#[test]
fn group_position_read_decodes_22_bit_replies() {
    let bus = VirtualBus::new(&unique("group-p"));
    // One get of P to the hand group 0x405; each puck answers on group 3 with 22-bit
    // two's complement counts, worked out by hand:
    //   F1 -1000    = 0x3FFC18 -> BF FC 18      F2 195000  = 0x02F9B8 -> 82 F9 B8
    //   F3 -2097152 = 0x200000 -> A0 00 00      spread 2097151 = 0x1FFFFF -> 9F FF FF
    let peer = scripted_peer(bus.endpoint(), 1, |_, _| {
        vec![
            CanFrame::new(0x563, &[0xBF, 0xFC, 0x18]).unwrap(),
            CanFrame::new(0x583, &[0x82, 0xF9, 0xB8]).unwrap(),
            CanFrame::new(0x5A3, &[0xA0, 0x00, 0x00]).unwrap(),
            CanFrame::new(0x5C3, &[0x9F, 0xFF, 0xFF]).unwrap(),
        ]
    });
    let mut hand = Hand::new(
        bus.endpoint(),
        Arc::new(ManualClock::new()),
        HandTiming::default(),
    );
    assert_eq!(
        hand.position_counts_all(CALL).unwrap(),
        [-1000, 195_000, -2_097_152, 2_097_151]
    );
    assert_eq!(peer.join().unwrap(), [frame(0x405, &[48])]);
}

#[test]
fn unsolicited_reply_is_reported_not_trusted() {
    let bus = VirtualBus::new(&unique("unexpected"));
    // Asked for F1's P, the peer answers with F2's (0x586).
    let peer = scripted_peer(bus.endpoint(), 1, |_, _| {
        vec![CanFrame::new(0x586, &[0xB0, 0x00, 0x10, 0x27, 0x00, 0x00]).unwrap()]
    });
    let mut hand = Hand::new(
        bus.endpoint(),
        Arc::new(ManualClock::new()),
        HandTiming::default(),
    );
    let err = hand.position_counts(Puck::F1, CALL).unwrap_err();
    let text = err.to_string();
    assert!(
        matches!(&err, HandError::Unexpected { puck: Puck::F2, frame, .. } if frame.id() == 0x586),
        "{text}"
    );
    assert!(
        text.contains("586#B00010270000") && text.contains("get P"),
        "{text}"
    );
    peer.join().unwrap();
}

#[test]
fn group_command_on_0x405_reaches_every_emulated_puck() {
    let bus = VirtualBus::new(&unique("group"));
    let mut rig = Rig::on_virtual_bus(&bus, HandEmulatorConfig::default(), HandTiming::default());
    rig.bring_up();
    let close_all = frame(group_id(5), &[0x80 | 29, 0x00, 18, 0, 0, 0]);
    assert_eq!(close_all.to_string(), "405#9D0012000000");
    bus.endpoint().send(&close_all).unwrap();
    // The manual clock has not moved: every puck has just started closing.
    for puck in Puck::ALL {
        let mode = rig.hand.get_property(puck, Property::Mode, CALL).unwrap();
        assert_eq!(mode, 5, "{puck}");
    }
    let mut emulator = rig.emulator();
    assert_eq!(emulator.stats().garbled, 0);
    assert_eq!(emulator.property(Puck::Spread, Property::Mode), Some(5));
}

// ---------------------------------------------------------------------------
// A real second process: `cell-sim-hand` on the cross-process bus.
// ---------------------------------------------------------------------------

/// Kills the child on every exit path.
struct ChildGuard(std::process::Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn hand_emulator_as_child_process_grasps() {
    let name = unique("child");
    let interface = format!("virtual:{name}");
    let dir = TempDir::new("can-child").unwrap();
    let candump = dir.join("hand.log");
    // This process hosts the hub; the emulator connects as another process.
    let bus = open_bus(&interface).unwrap();
    let mut child = ChildGuard(
        std::process::Command::new(env!("CARGO_BIN_EXE_cell-sim-hand"))
            .args(["--interface", &interface, "--contact-rad", "1.0,1.1,1.2"])
            .arg("--candump")
            .arg(&candump)
            .args(["--boot-s", "0.2"])
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut ready = String::new();
    BufReader::new(child.0.stdout.take().unwrap())
        .read_line(&mut ready)
        .unwrap();
    assert_eq!(ready.trim(), format!("ready {interface}"));

    let mut hand = Hand::new(bus, Arc::new(SystemClock::new()), HandTiming::default());
    let call = Duration::from_secs(20);
    hand.wake(call).unwrap();
    hand.identify(call).unwrap();
    hand.initialise(call).unwrap();
    let closed = hand.close(call).unwrap();
    assert_stalled_at(&closed, [1.0, 1.1, 1.2], "child process");
    let opened = hand.open(call).unwrap();
    assert!(opened.iter().all(|o| o.reached_target), "{opened:?}");
    drop(child);

    // The child's candump log has the close command to F1 in candump's format.
    let log = std::fs::read_to_string(&candump).unwrap();
    let close_f1 = log
        .lines()
        .find(|l| l.ends_with(&format!(" {interface} 00B#9D0012000000")))
        .unwrap_or_else(|| panic!("no CMD = C to F1 in the log:\n{log}"));
    let stamp = close_f1.split(' ').next().unwrap();
    assert!(
        stamp.starts_with('(') && stamp.ends_with(')') && stamp.len() == 19,
        "{close_f1}"
    );
}
