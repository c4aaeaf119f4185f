//! One AFL++ harness for every input reader: `hslt-fuzz TARGET` with TARGET one of
//! `hslt::fuzzing::Input`'s names (scene_xml, obj, ply, exr, png). A panic or abort is a crash.

fn main() {
    let name = std::env::args().nth(1).unwrap_or_default();
    let Some(input) = hslt::fuzzing::Input::parse(&name) else {
        eprintln!("usage: hslt-fuzz TARGET (scene_xml, obj, ply, exr, png)");
        std::process::exit(2);
    };
    afl::fuzz!(|data: &[u8]| {
        let _ = hslt::fuzzing::feed(input, data);
    });
}
