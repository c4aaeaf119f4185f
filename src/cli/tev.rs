//! `--tev [HOST:PORT]`: the image so far, streamed to a running tev (Thomas Müller's HDR viewer) over
//! its TCP protocol through the `tev_client` crate: one create-image packet when the render starts,
//! then update-image packets in bands of rows at most once per `TEV_INTERVAL`, and the final image.
//! Without a listening tev the render goes on after one warning; so it does when tev goes away.

use crate::image::ImageBuf;
use std::net::{TcpStream, ToSocketAddrs};
use std::time::Duration;
use tev_client::{PacketCreateImage, PacketUpdateImage, TevClient};

/// Where tev listens unless told otherwise (tev's own default).
pub const TEV_DEFAULT_ADDRESS: &str = "127.0.0.1:14158";

/// How often the live view is refreshed: often enough to watch, rare enough that building and
/// sending the image costs the render nothing measurable.
pub const TEV_INTERVAL: Duration = Duration::from_secs(1);

/// Rows per update packet, so no packet grows with the image (a 4K RGB band of 64 rows is 6 MB).
const ROWS_PER_PACKET: usize = 64;

const CHANNELS: [&str; 3] = ["R", "G", "B"];

/// A connection to tev, or none after a failure (reported once).
pub struct TevStream {
    client: Option<TevClient>,
    address: String,
    name: String,
}

impl TevStream {
    /// Connects and creates a black `width`×`height` image named `name`; warns and carries on
    /// without a view when nothing answers at `address`.
    pub fn connect(address: &str, name: &str, width: usize, height: usize) -> TevStream {
        let mut stream = TevStream { client: None, address: address.to_string(), name: name.to_string() };
        match open(address) {
            Ok(socket) => {
                stream.client = Some(TevClient::wrap(socket));
                let create = PacketCreateImage {
                    image_name: name,
                    grab_focus: true,
                    width: width as u32,
                    height: height as u32,
                    channel_names: &CHANNELS,
                };
                let result = stream.client.as_mut().map(|c| c.send(create));
                stream.check(result);
            }
            Err(e) => eprintln!("warning: --tev: no tev at {address} ({e}); rendering without a live view"),
        }
        stream
    }

    pub fn is_connected(&self) -> bool {
        self.client.is_some()
    }

    /// Sends `image` (RGB) as update packets of `ROWS_PER_PACKET` rows each.
    pub fn send(&mut self, image: &ImageBuf) {
        if image.channels != 3 || image.width == 0 {
            return;
        }
        for y0 in (0..image.height).step_by(ROWS_PER_PACKET) {
            let rows = ROWS_PER_PACKET.min(image.height - y0);
            let band = &image.data[y0 * image.width * 3..(y0 + rows) * image.width * 3];
            // tev shows what it gets; a NaN would poison its exposure statistics.
            let clean: Vec<f32> = band.iter().map(|&v| if v.is_finite() { v } else { 0.0 }).collect();
            let update = PacketUpdateImage {
                image_name: &self.name,
                grab_focus: false,
                channel_names: &CHANNELS,
                channel_offsets: &[0, 1, 2],
                channel_strides: &[3, 3, 3],
                x: 0,
                y: y0 as u32,
                width: image.width as u32,
                height: rows as u32,
                data: &clean,
            };
            let Some(client) = self.client.as_mut() else { return };
            let result = Some(client.send(update));
            self.check(result);
        }
    }

    fn check(&mut self, result: Option<std::io::Result<()>>) {
        if let Some(Err(e)) = result {
            eprintln!("warning: --tev: lost the connection to {} ({e}); the render goes on", self.address);
            self.client = None;
        }
    }
}

fn open(address: &str) -> std::io::Result<TcpStream> {
    let mut last = std::io::Error::new(std::io::ErrorKind::NotFound, "the address resolves to nothing");
    for addr in address.to_socket_addrs()? {
        match TcpStream::connect_timeout(&addr, Duration::from_secs(2)) {
            Ok(socket) => {
                socket.set_write_timeout(Some(Duration::from_secs(5)))?;
                return Ok(socket);
            }
            Err(e) => last = e,
        }
    }
    Err(last)
}
