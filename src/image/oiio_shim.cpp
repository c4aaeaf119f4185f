// C ABI around OpenImageIO (>= 2.2, tested with 2.4.7) for hslt's image module.
//
// Contract with src/image/oiio.rs:
//  - No C++ exception ever leaves this file: every entry point catches everything and reports it
//    as an error string.
//  - Error strings are heap-allocated here (malloc) and must be released with hslt_oiio_free_string.
//  - Pixel buffers are always owned by the caller; the shim never keeps a pointer past a call.
//  - OIIO's own thread pool is capped to one thread before the first use, so that it does not
//    oversubscribe the cores that rayon already uses for rendering.

#include <OpenImageIO/imageio.h>
#include <OpenImageIO/oiioversion.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace {

void configure_oiio_once() {
    static std::once_flag flag;
    std::call_once(flag, [] { OIIO::attribute("threads", 1); });
}

char* copy_to_c_string(const std::string& s) {
    char* out = static_cast<char*>(std::malloc(s.size() + 1));
    if (out != nullptr) {
        std::memcpy(out, s.c_str(), s.size() + 1);
    }
    return out;
}

// Stores `message` (or a fallback if it is empty) into *err for the caller.
void report(char** err, std::string message, const char* fallback) {
    if (err == nullptr) {
        return;
    }
    if (message.empty()) {
        message = fallback;
    }
    *err = copy_to_c_string(message);
}

// Global OIIO error text (set by create/open failures that happen before an object exists).
std::string global_error() {
    return OIIO::geterror();
}

// IEC 61966-2-1 sRGB opto-electronic transfer function (linear -> encoded), with the
// linear segment below 0.0031308. Input must already be clamped to [0, 1].
float linear_to_srgb(float x) {
    if (x <= 0.0031308f) {
        return 12.92f * x;
    }
    return 1.055f * std::pow(x, 1.0f / 2.4f) - 0.055f;
}

uint8_t quantize_srgb8(float linear) {
    // NaN compares false, so the negated form maps it to 0 (defence in depth; Rust already filters).
    float clamped = !(linear > 0.0f) ? 0.0f : std::min(linear, 1.0f);
    float encoded = linear_to_srgb(clamped);
    return static_cast<uint8_t>(std::lround(encoded * 255.0f));
}

// Formats that store floating-point data natively get linear float pixels; every other format
// (PNG, JPEG, BMP, TGA, GIF, WebP...) gets 8-bit sRGB, which is what image viewers expect.
bool stores_float(const std::string& format_name) {
    return format_name == "openexr" || format_name == "hdr" || format_name == "tiff" ||
           format_name == "fits";
}

bool iequals(OIIO::string_view a, const char* b) {
    size_t n = std::strlen(b);
    if (a.size() != n) {
        return false;
    }
    for (size_t i = 0; i < n; ++i) {
        if (std::tolower(static_cast<unsigned char>(a[i])) !=
            std::tolower(static_cast<unsigned char>(b[i]))) {
            return false;
        }
    }
    return true;
}

bool starts_with_ci(OIIO::string_view a, const char* prefix) {
    size_t n = std::strlen(prefix);
    return a.size() >= n && iequals(a.substr(0, n), prefix);
}

}  // namespace

extern "C" {

// Colour encoding of a file's pixel values as reported by hslt_oiio_open.
enum HsltColorEncoding { HSLT_LINEAR = 0, HSLT_SRGB = 1, HSLT_GAMMA = 2 };

struct HsltImageInfo {
    int width;
    int height;
    int channels;
    int encoding;  // HsltColorEncoding
    float gamma;   // meaningful for HSLT_GAMMA only
};

void hslt_oiio_free_string(char* s) { std::free(s); }

// Returns a malloc'd version string ("2.4.7") to be freed with hslt_oiio_free_string, or null.
char* hslt_oiio_version() {
    try {
        configure_oiio_once();
        return copy_to_c_string(OIIO_VERSION_STRING);
    } catch (...) {
        return nullptr;
    }
}

// Opens `path` for reading and fills `info`. On success returns an opaque handle (to be closed
// with hslt_oiio_close); on failure returns null and sets *err.
void* hslt_oiio_open(const char* path, HsltImageInfo* info, char** err) {
    try {
        configure_oiio_once();
        // OIIO premultiplies unassociated-alpha files (PNG, TGA...) on read by default; hslt keeps
        // the stored values, so ask for them untouched.
        OIIO::ImageSpec config;
        config.attribute("oiio:UnassociatedAlpha", 1);
        std::unique_ptr<OIIO::ImageInput> in = OIIO::ImageInput::open(path, &config);
        if (!in) {
            report(err, global_error(), "OpenImageIO could not open the file");
            return nullptr;
        }
        const OIIO::ImageSpec& spec = in->spec();
        if (spec.depth > 1) {
            report(err, "volume images (depth > 1) are not supported", "");
            return nullptr;
        }
        info->width = spec.width;
        info->height = spec.height;
        info->channels = spec.nchannels;
        info->gamma = 1.0f;

        OIIO::string_view space = spec.get_string_attribute("oiio:ColorSpace");
        if (iequals(space, "sRGB")) {
            info->encoding = HSLT_SRGB;
        } else if (starts_with_ci(space, "Gamma")) {
            // OIIO 2.4 names power-law files "GammaCorrected<g>" / "Gamma<g>" and stores g in
            // "oiio:Gamma"; 2.2 is the usual value when the attribute is missing.
            info->encoding = HSLT_GAMMA;
            info->gamma = spec.get_float_attribute("oiio:Gamma", 2.2f);
        } else if (space.empty() &&
                   (spec.format == OIIO::TypeDesc::UINT8 || spec.format == OIIO::TypeDesc::UINT16)) {
            // Integer files without a declared colour space are display-referred in practice.
            info->encoding = HSLT_SRGB;
        } else {
            info->encoding = HSLT_LINEAR;
        }
        return in.release();
    } catch (const std::exception& e) {
        report(err, e.what(), "C++ exception");
    } catch (...) {
        report(err, "unknown C++ exception in OpenImageIO", "");
    }
    return nullptr;
}

// Reads all channels of subimage 0, mip level 0 as float into `out` (len = w*h*channels floats).
// Returns 0 on success, nonzero with *err set on failure.
int hslt_oiio_read(void* handle, float* out, size_t out_len, char** err) {
    try {
        auto* in = static_cast<OIIO::ImageInput*>(handle);
        const OIIO::ImageSpec& spec = in->spec();
        size_t expected = size_t(spec.width) * size_t(spec.height) * size_t(spec.nchannels);
        if (expected != out_len) {
            report(err, "pixel buffer size does not match the image", "");
            return 1;
        }
        // The explicit subimage/miplevel form is the thread-safe one in OIIO 2.x.
        if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, out)) {
            report(err, in->geterror(), "OpenImageIO failed to read the pixels");
            return 1;
        }
        return 0;
    } catch (const std::exception& e) {
        report(err, e.what(), "C++ exception");
    } catch (...) {
        report(err, "unknown C++ exception in OpenImageIO", "");
    }
    return 1;
}

void hslt_oiio_close(void* handle) {
    try {
        auto* in = static_cast<OIIO::ImageInput*>(handle);
        if (in != nullptr) {
            in->close();
            delete in;
        }
    } catch (...) {
        // Nothing useful to report on close of an input; swallowing keeps the C ABI exception-free.
    }
}

// Writes linear float pixels (`channels` per pixel, row-major, top row first) to `path`, choosing
// the format from its extension. 8-bit formats receive clamped, sRGB-encoded, rounded values; alpha
// is dropped for formats without alpha. `keys`/`values` are `n_meta` string attributes.
// Returns 0 on success, nonzero with *err set on failure.
int hslt_oiio_write(const char* path, const float* data, int width, int height, int channels,
                    const char* const* keys, const char* const* values, int n_meta, char** err) {
    try {
        configure_oiio_once();
        std::unique_ptr<OIIO::ImageOutput> out = OIIO::ImageOutput::create(path);
        if (!out) {
            report(err, global_error(), "OpenImageIO has no writer for this file extension");
            return 1;
        }
        const std::string format = out->format_name();
        const bool as_float = stores_float(format);
        int out_channels = channels;
        if ((channels == 4 || channels == 2) && !out->supports("alpha")) {
            out_channels = channels - 1;
        }

        OIIO::ImageSpec spec(width, height, out_channels,
                             as_float ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::UINT8);
        if (out_channels >= 3) {
            spec.channelnames = {"R", "G", "B"};
            if (out_channels == 4) {
                spec.channelnames.push_back("A");
                spec.alpha_channel = 3;
            }
        } else if (out_channels == 2) {
            spec.channelnames = {"Y", "A"};
            spec.alpha_channel = 1;
        } else {
            spec.channelnames = {"Y"};
        }
        spec.attribute("oiio:ColorSpace", as_float ? "Linear" : "sRGB");
        // Our alpha is straight (unassociated); without this OIIO's PNG writer would divide colour
        // by alpha, assuming premultiplied input.
        spec.attribute("oiio:UnassociatedAlpha", 1);
        for (int i = 0; i < n_meta; ++i) {
            spec.attribute(keys[i], values[i]);
        }

        const size_t pixels = size_t(width) * size_t(height);
        if (!out->open(path, spec)) {
            report(err, out->geterror(), "OpenImageIO could not create the file");
            return 1;
        }
        bool ok;
        if (as_float) {
            std::vector<float> buf(pixels * out_channels);
            for (size_t p = 0; p < pixels; ++p) {
                for (int c = 0; c < out_channels; ++c) {
                    buf[p * out_channels + c] = data[p * channels + c];
                }
            }
            ok = out->write_image(OIIO::TypeDesc::FLOAT, buf.data());
        } else {
            std::vector<uint8_t> buf(pixels * out_channels);
            for (size_t p = 0; p < pixels; ++p) {
                for (int c = 0; c < out_channels; ++c) {
                    float v = data[p * channels + c];
                    bool is_alpha = c == spec.alpha_channel;
                    // Alpha is coverage, not colour: quantise it linearly.
                    buf[p * out_channels + c] =
                        is_alpha ? static_cast<uint8_t>(std::lround(
                                       (!(v > 0.0f) ? 0.0f : std::min(v, 1.0f)) * 255.0f))
                                 : quantize_srgb8(v);
                }
            }
            ok = out->write_image(OIIO::TypeDesc::UINT8, buf.data());
        }
        if (!ok) {
            report(err, out->geterror(), "OpenImageIO failed to write the pixels");
            out->close();
            return 1;
        }
        if (!out->close()) {
            report(err, out->geterror(), "OpenImageIO failed to finish the file");
            return 1;
        }
        return 0;
    } catch (const std::exception& e) {
        report(err, e.what(), "C++ exception");
    } catch (...) {
        report(err, "unknown C++ exception in OpenImageIO", "");
    }
    return 1;
}

}  // extern "C"
