//! The hub's relay latency: one GridConnect frame from one client to another and one back,
//! through a [`Hub`] on 127.0.0.1 (two relays, with the clients' socket calls), the round trip
//! a datagram and its Datagram OK make between a tool and a board.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;

use criterion::{Criterion, criterion_group, criterion_main};
use openlcb_tokio::{Hub, HubOptions};

const REQUEST: &[u8] = b":X1A323AAAN2000000000EF0102;\n";
const ANSWER: &[u8] = b":X19A28323N0AAA;\n";

/// A client of the hub: a blocking socket and a reader of its lines.
struct Client {
    socket: TcpStream,
    lines: BufReader<TcpStream>,
    line: Vec<u8>,
}

impl Client {
    fn connect(addr: std::net::SocketAddr) -> Client {
        let socket = TcpStream::connect(addr).expect("connect to the hub");
        socket.set_nodelay(true).expect("nodelay");
        socket.set_read_timeout(Some(std::time::Duration::from_secs(5))).expect("timeout");
        let lines = BufReader::new(socket.try_clone().expect("clone"));
        Client { socket, lines, line: Vec::new() }
    }

    fn send(&mut self, line: &[u8]) {
        self.socket.write_all(line).expect("write to the hub");
    }

    /// Reads the next line and checks it is `expected`.
    fn expect(&mut self, expected: &[u8]) {
        self.line.clear();
        self.lines.read_until(b'\n', &mut self.line).expect("read from the hub");
        assert_eq!(self.line, expected, "the hub relayed another line");
    }
}

fn round_trip(c: &mut Criterion) {
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    let hub = runtime.block_on(Hub::bind("127.0.0.1:0", None, HubOptions::default())).expect("hub");
    let (mut tool, mut board) = (Client::connect(hub.local_addr()), Client::connect(hub.local_addr()));
    // Both are clients once a line from each went through.
    tool.send(ANSWER);
    board.expect(ANSWER);
    c.bench_function("hub: a frame there and one back (two relays)", |b| {
        b.iter(|| {
            tool.send(REQUEST);
            board.expect(REQUEST);
            board.send(ANSWER);
            tool.expect(ANSWER);
        })
    });
    drop(hub);
}

criterion_group!(benches, round_trip);
criterion_main!(benches);
