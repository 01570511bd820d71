//! A NATS subscriber for a mouthpiece booth (docs/nats.md), with `async-nats`.
//!
//! Asks the booth for its `hello`, then prints each frame's sequence number, stream time,
//! latency (from the `Mouthpiece-Sent-Us` header) and each character's jaw opening.
//!
//! ```text
//! cargo run -p mouthpiece-nats --example subscriber -- nats://127.0.0.1:4222 booth-a 30
//! ```

use futures_util::StreamExt;

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let server = args
        .next()
        .unwrap_or_else(|| "nats://127.0.0.1:4222".into());
    let booth = args.next().unwrap_or_else(|| "booth-a".into());
    let frames: usize = args.next().map_or(Ok(30), |n| n.parse())?;

    let client = async_nats::connect(server.as_str()).await?;
    let hello = client
        .request(format!("mouthpiece.{booth}.hello"), "".into())
        .await?;
    let hello: serde_json::Value = serde_json::from_slice(&hello.payload)?;
    let names: Vec<&str> = hello["characters"]
        .as_array()
        .map(|a| a.iter().filter_map(|c| c["name"].as_str()).collect())
        .unwrap_or_default();
    println!("hello: characters {}", names.join(", "));

    let mut subscription = client
        .subscribe(format!("mouthpiece.{booth}.frame"))
        .await?;
    for _ in 0..frames {
        let Some(message) = subscription.next().await else {
            break;
        };
        let now_us = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)?
            .as_micros() as i64;
        let sent_us: Option<i64> = message
            .headers
            .as_ref()
            .and_then(|h| h.get("Mouthpiece-Sent-Us"))
            .and_then(|v| v.as_str().parse().ok());
        let frame: serde_json::Value = serde_json::from_slice(&message.payload)?;
        let jaws: Vec<String> = frame["characters"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|c| {
                let jaw = c["rig"]["curves"]["jawOpen"].as_f64()?;
                Some(format!("{} jawOpen {jaw:.3}", c["name"].as_str()?))
            })
            .collect();
        println!(
            "seq {} t {:.3} latency {} {}",
            frame["seq"],
            frame["t"].as_f64().unwrap_or(0.0),
            sent_us.map_or("?".into(), |s| format!(
                "{:.2} ms",
                (now_us - s) as f64 / 1e3
            )),
            jaws.join("; ")
        );
    }
    Ok(())
}
