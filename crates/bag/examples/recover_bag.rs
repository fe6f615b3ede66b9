//! Recovers a bag whose writer was killed, as `oilfilm bag recover DIR` will:
//!
//!     recover_bag DIR
//!
//! prints what was kept per file.

fn main() -> anyhow::Result<()> {
    let dir = std::env::args().nth(1).ok_or_else(|| anyhow::anyhow!("usage: recover_bag DIR"))?;
    let r = oilfilm_bag::recover(&dir)?;
    for f in &r.files {
        let how = match (&f.original, &f.stop) {
            (Some(o), Some(s)) => format!("rewritten ({} at byte {}); original kept as {}", s.what, s.offset, o.display()),
            (Some(o), None) => format!("set aside as {}", o.display()),
            (None, _) => "sound, kept as it was".into(),
        };
        println!("{}: {} messages in {} chunks, {how}", f.path.display(), f.messages, f.chunks);
    }
    println!("{} messages; metadata.yaml written", r.messages());
    Ok(())
}
