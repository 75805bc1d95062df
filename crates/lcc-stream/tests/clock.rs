//! `lcc-stream clock` as separate processes through a hub on 127.0.0.1: a generator, a
//! consumer that follows it, and the commands that drive it. Every wait is bounded.

mod common;

use common::{bounded, command, interrupt, spawn, until};
use openlcb_tokio::{Hub, HubOptions};
use tokio::io::{AsyncBufReadExt, BufReader, Lines};
use tokio::process::{ChildStderr, ChildStdout};

async fn run(args: &[&str]) -> (i32, String) {
    let out = bounded("a command", command(args).output()).await.unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8(out.stderr).unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_generator_is_followed_set_stopped_and_its_rate_changed_from_other_processes() {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut generator =
        spawn(&["clock", "--connect", &addr, "--rate", "60", "--time", "06:00", "--date", "1956-07-04"]);
    let mut generated: Lines<BufReader<ChildStderr>> = BufReader::new(generator.stderr.take().unwrap()).lines();
    until(&mut generated, "generating default-fast").await;
    let mut follower = spawn(&["clock", "--follow", "--json", "--connect", &addr]);
    let mut followed: Lines<BufReader<ChildStdout>> = BufReader::new(follower.stdout.take().unwrap()).lines();
    let synced = until(&mut followed, "\"synchronized\"").await;
    assert!(synced.contains("1956-07-04 06:0"), "{synced}");

    let (code, said) = run(&["clock", "set", "--time", "08:30", "--connect", &addr]).await;
    assert_eq!(code, 0, "{said}");
    assert!(said.contains("default-fast time 08:30"), "{said}");
    let set = until(&mut followed, "\"set\"").await;
    assert!(set.contains("1956-07-04 08:30:00"), "{set}");

    let (code, said) = run(&["clock", "stop", "--connect", &addr]).await;
    assert_eq!(code, 0, "{said}");
    until(&mut followed, "\"stopped\"").await;
    let (code, said) = run(&["clock", "rate", "0", "--connect", &addr]).await;
    assert_eq!(code, 0, "{said}");
    assert!(said.contains("asked rate 0") && said.contains("made it rate 0.25"), "{said}");
    let rate = until(&mut followed, "\"rate\"").await;
    assert!(rate.contains("\"rate\":\"0.25\"") && rate.contains("\"running\":false"), "{rate}");

    // Another clock has no generator: the command says so and exits 5.
    let (code, said) = run(&["clock", "start", "--clock", "alternate-2", "--connect", &addr]).await;
    assert_eq!(code, 5, "{said}");
    assert!(said.contains("no generator of alternate-2 confirmed"), "{said}");

    interrupt(&follower).await;
    interrupt(&generator).await;
    for child in [&mut follower, &mut generator] {
        assert!(bounded("the clock to stop", child.wait()).await.unwrap().success());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_times_dates_and_rates_are_usage_errors() {
    for args in [
        &["clock", "set", "--time", "24:00", "--connect", "127.0.0.1:1"][..],
        &["clock", "set", "--date", "2023-02-29", "--connect", "127.0.0.1:1"],
        &["clock", "rate", "0.3", "--connect", "127.0.0.1:1"],
        &["clock", "--rate", "600", "--connect", "127.0.0.1:1"],
        &["clock", "--clock", "fastest", "--connect", "127.0.0.1:1"],
        &["clock", "set", "--connect", "127.0.0.1:1"],
    ] {
        let (code, said) = run(args).await;
        assert_eq!(code, 2, "{args:?}: {said}");
    }
}

/// A generator that loses its hub joins the next one on the same address and goes on from
/// the time it had (not from its start): a new follower sees the time run on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_generator_goes_on_from_its_time_through_a_lost_hub() {
    let hub = Hub::bind("127.0.0.1:0", None, HubOptions::default()).await.unwrap();
    let addr = hub.local_addr().to_string();
    let mut generator =
        spawn(&["clock", "--connect", &addr, "--rate", "60", "--time", "06:00", "--date", "1956-07-04"]);
    let mut said: Lines<BufReader<ChildStderr>> = BufReader::new(generator.stderr.take().unwrap()).lines();
    until(&mut said, "generating default-fast").await;
    let mut generated: Lines<BufReader<ChildStdout>> = BufReader::new(generator.stdout.take().unwrap()).lines();
    until(&mut generated, "06:03:00").await;
    drop(hub);
    until(&mut said, "lost the hub").await;
    let hub = bounded("the address free again", async {
        loop {
            match Hub::bind(&addr, None, HubOptions::default()).await {
                Ok(hub) => return hub,
                Err(_) => tokio::time::sleep(std::time::Duration::from_millis(50)).await,
            }
        }
    })
    .await;
    until(&mut said, "rejoined the hub").await;
    let mut follower = spawn(&["clock", "--follow", "--json", "--connect", &addr]);
    let mut followed: Lines<BufReader<ChildStdout>> = BufReader::new(follower.stdout.take().unwrap()).lines();
    let synced = until(&mut followed, "\"synchronized\"").await;
    let shown: serde_json::Value = serde_json::from_str(&synced).unwrap();
    let time = shown["clock_time"].as_str().unwrap().to_string();
    assert!(time.as_str() >= "1956-07-04 06:03:00" && time.as_str() < "1956-07-04 07:00:00", "{time}");
    interrupt(&follower).await;
    interrupt(&generator).await;
    for child in [&mut follower, &mut generator] {
        assert!(bounded("the clock to stop", child.wait()).await.unwrap().success());
    }
    drop(hub);
}
