//! An 8-line I/O board, the whole OpenLCB node, as Cortex-M0 firmware (QEMU's `microbit`,
//! an nRF51822; its budget is 32 KiB of flash and 8 KiB of RAM, which `.ci/size-report`
//! prints it against).
//!
//! The node: the CAN link (alias login, duplicate detection) through the `openlcb-embedded`
//! driver on the UART, which carries the CAN frames in binary (`serial_can`), datagrams, SNIP,
//! PIP, Memory Configuration with the CDI, the ACDI and a configuration space that flash
//! keeps, events bound to that configuration (lines 1-4 produce theirs, 5-8 consume theirs
//! and print what they do), a firmware image space (0xEF) as a bootloader space, Reset/Reboot
//! as a real reset. Memory Configuration's optional commands (Write Under Mask, Lock, Get
//! Unique ID) are left out, as OpenMRN's nodes leave them. Its configuration is declared once
//! with the kit (`openlcb_node::board`): the CDI and the offsets come from the same calls.
//!
//! Semihosting is its console: where its RAM's figures are (`ram layout: ...`, at start-up),
//! each consumed event it acts on (`line 5 on`), each image it takes. `.ci/firmware-m0` runs
//! it against a bus the test drives (`cargo test -p openlcb-tokio --test cortex_m0 --
//! --ignored`), which also measures the RAM the run used from a copy of it.

#![no_std]
#![no_main]

extern crate alloc;

mod flash;
mod heap;
mod mem;
mod nrf51;
mod ram;
mod serial_can;

use alloc::vec::Vec;
use core::mem::MaybeUninit;

use cortex_m_rt::{ExceptionFrame, entry, exception};
use openlcb_can::{CanConfig, CanLink};
use openlcb_embedded::Driver;
use openlcb_node::board::{Board, BoardBuilder, CdiSpace, EventRole, EventSetting};
use openlcb_node::{EventNotice, MemoryEvent, MemoryServer, MemorySpace, Node, NodeConfig, NodeEvent, SnipInfo};
use openlcb_stream::{EventId, NodeId};

use crate::flash::{ConfigSpace, FirmwareSpace};
use crate::ram::print;

/// The board's Node ID.
const NODE_ID: u64 = 0x05_01_01_01_22_D0;

/// One line's events.
struct Line {
    on: EventSetting,
    off: EventSetting,
}

/// The configuration: a name, and per line a name, a mode and two events (lines 1-4 inputs,
/// 5-8 outputs), the factory events the Node ID's, two a line. A function, so that the CDI
/// space can run it again for each read ([`Board::declare`]).
fn settings(config: &mut BoardBuilder) -> Vec<Line> {
    config.string("Board name", 16, "");
    config.group("Line", 8, |g, i| {
        let (role, mode) = if i < 4 { (EventRole::Produced, 0) } else { (EventRole::Consumed, 1) };
        g.string("Name", 8, "");
        g.int("Mode", 1, mode, &[(0, "Input"), (1, "Output")]);
        let event = |k| EventId(NODE_ID << 16 | u64::from(2 * i + k));
        Line { on: g.event("Event On", role, event(0)), off: g.event("Event Off", role, event(1)) }
    })
}

/// What the node says about itself.
fn snip() -> SnipInfo {
    SnipInfo {
        manufacturer: "openlcb-stream".into(),
        model: "Cortex-M0 I/O board".into(),
        hardware_version: "QEMU microbit".into(),
        software_version: env!("CARGO_PKG_VERSION").into(),
        ..Default::default()
    }
}

/// The configuration space of a running node.
fn config_space(node: &mut Node) -> &mut (dyn MemorySpace + Send + 'static) {
    match node.memory_server_mut().and_then(|server| server.space_mut(0xFD)) {
        Some(space) => space,
        None => fail("no space 0xFD"),
    }
}

/// Prints what an output line does with `event`, if it is one of theirs.
fn act_on(lines: &[Line], space: &mut (dyn MemorySpace + Send), event: EventId) {
    for (i, line) in lines.iter().enumerate().skip(4) {
        let state: &[u8] = if line.on.read(space).ok() == Some(event) {
            b"on\n"
        } else if line.off.read(space).ok() == Some(event) {
            b"off\n"
        } else {
            continue;
        };
        print(&[b"line ", ram::digits(i as u32 + 1).as_bytes(), b" ", state]);
    }
}

/// The CAN link's tables, sized for a board that answers tools and talks to few peers (the
/// defaults suit a PC tool): aliases of 8 peers (those it answers, learnt from their frames);
/// 2 messages other than datagrams reassembled at once, of up to 72 bytes (a board takes in
/// few: a PCER with a payload, a tool's SNIP reply); 2 messages queued (the driver hands the
/// link the node's next message only when it has room: the node's own queue holds the rest),
/// 2 of them waiting for an alias; 8 frames; 2 datagrams in flight.
fn can_config() -> CanConfig {
    let mut config = CanConfig::default();
    config.alias_cache_size = 8;
    config.reassembly_slots = 2;
    config.max_message_len = 72;
    config.transmit_queue_limit = 2;
    config.unresolved_limit = 2;
    config.frame_queue_limit = 8;
    config.datagram_slots = 2;
    config
}

/// The board's driver: the CAN link on the UART's GridConnect bus, timed by TIMER0.
type BoardDriver = Driver<serial_can::SerialCan, nrf51::Clock>;

/// The node's configuration: its events as the configuration space holds them, what it says
/// about itself, its tables sized.
fn node_config(board: &Board, config: &mut ConfigSpace, snip: SnipInfo) -> NodeConfig {
    let mut node_config = NodeConfig::default();
    node_config.events = board.events(config);
    node_config.snip = snip;
    // The node's tables, sized for a board (the defaults suit a PC tool): 2 datagrams queued
    // (Memory Configuration's replies), 1 per destination. It has no streams, makes no SNIP
    // requests and takes no datagrams itself (`openlcb-node` without its `streams`,
    // `snip-client` and `app-datagrams` features): the image comes by datagrams.
    node_config.datagrams.max_outgoing = 2;
    node_config.datagrams.max_outgoing_per_destination = 1;
    node_config.transmit_queue_limit = 16;
    node_config
}

/// The memory spaces: the CDI, the configuration, the firmware image, the ACDI.
#[inline(never)]
fn memory_server(cdi: CdiSpace<Vec<Line>>, config: ConfigSpace) -> MemoryServer {
    MemoryServer::new()
        .with_space(0xFF, cdi)
        .with_space(0xFD, config)
        .with_space(0xEF, FirmwareSpace::new())
        .with_acdi()
}

#[entry]
fn main() -> ! {
    ram::paint_stack();
    ram::init_heap();
    ram::print_layout();
    let Some(id) = NodeId::new(NODE_ID) else { fail("bad Node ID") };
    let (board, lines, node) = start(id);
    // Last before the loop: the login's 200 ms count from the link's creation.
    let driver = connect(id);
    let mut rebooting = false;
    loop {
        let Some(idle) = poll(driver, node) else { continue };
        if rebooting && idle {
            nrf51::reset();
        }
        while let Some(event) = node.poll_event() {
            rebooting |= on_event(event, &board, &lines, node);
        }
    }
}

/// The board declared, then its node built, its configuration space loaded (or its defaults
/// written). The node (0.7 KiB) lives in static RAM, placed there by `ram::place`, out of
/// `main`'s frame. Apart from `main` and out of line, like the declaration before it, so that
/// what they need on the stack is given back before the node runs.
#[inline(never)]
fn start(id: NodeId) -> (Board, Vec<Line>, &'static mut Node) {
    let (board, lines, cdi, snip) = declare();
    let (mut config, found) = ConfigSpace::load(board.len());
    if !found && board.factory_reset(&mut config).is_err() {
        fail("factory reset");
    }
    let Some(slot) = cortex_m::singleton!(: MaybeUninit<Node> = MaybeUninit::uninit()) else {
        fail("node built twice")
    };
    let node = ram::place(slot, || Node::new(id, node_config(&board, &mut config, snip)));
    node.set_memory_server(memory_server(cdi, config));
    print(&[b"booted\n"]);
    (board, lines, node)
}

/// The board declared: its layout, defaults and events, its lines' settings, its CDI space,
/// and what it says about itself.
#[inline(never)]
fn declare() -> (Board, Vec<Line>, CdiSpace<Vec<Line>>, SnipInfo) {
    let snip = snip();
    let (board, lines, cdi) = Board::declare("I/O board", &snip, settings);
    (board, lines, cdi, snip)
}

/// The CAN link and its driver, in static RAM like the node. The login's 200 ms count from
/// here: the first poll sends its CIDs.
#[inline(never)]
fn connect(id: NodeId) -> &'static mut BoardDriver {
    let Some(slot) = cortex_m::singleton!(: MaybeUninit<BoardDriver> = MaybeUninit::uninit()) else {
        fail("driver built twice")
    };
    ram::place(slot, || {
        let mut clock = nrf51::Clock::new();
        let link = CanLink::new(clock.now(), id, can_config());
        Driver::new(serial_can::SerialCan::new(nrf51::Uart::new()), clock, link)
    })
}

/// One poll of the driver: whether it left nothing to do (`None`: the peripheral failed).
#[inline(never)]
fn poll(driver: &mut BoardDriver, node: &mut Node) -> Option<bool> {
    driver.poll(node).ok().map(|poll| poll.is_idle())
}

/// Acts on one event of the node: whether it asks for a reset.
#[inline(never)]
fn on_event(event: NodeEvent, board: &Board, lines: &[Line], node: &mut Node) -> bool {
    match event {
        NodeEvent::Memory(MemoryEvent::UpdateComplete { .. }) => {
            if cfg!(feature = "inject-hardfault") {
                cortex_m::asm::udf();
            }
            if !cfg!(feature = "inject-stale-events") {
                take_events(board, node);
            }
        }
        NodeEvent::Memory(MemoryEvent::FactoryResetRequested { .. }) => {
            if board.factory_reset(config_space(node)).is_err() {
                fail("factory reset");
            }
            take_events(board, node);
        }
        NodeEvent::Memory(MemoryEvent::ResetRequested { .. }) => return true,
        NodeEvent::Memory(MemoryEvent::Unfrozen { image_len, .. }) => {
            print(&[b"firmware image of ", ram::digits(image_len).as_bytes(), b" bytes\n"]);
        }
        NodeEvent::Events(EventNotice::Report { event, .. }) => act_on(lines, config_space(node), event),
        _ => {}
    }
    false
}

/// The node produces and consumes the events its configuration holds now.
fn take_events(board: &Board, node: &mut Node) {
    let events = board.events(config_space(node));
    node.set_events(events);
}

/// Ends the run with a failure: QEMU exits with status 1.
fn fail(why: &str) -> ! {
    print(&[b"FAIL: ", why.as_bytes(), b"\n"]);
    ram::exit_failure()
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo<'_>) -> ! {
    // No location: its file names would take 3 KiB of flash.
    fail("panicked")
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    print(&[b"HardFault at pc ", ram::digits(frame.pc()).as_bytes(), b"\n"]);
    fail("HardFault")
}
