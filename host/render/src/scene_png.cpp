// PNG writing without zlib: the image data goes into "stored" (uncompressed) deflate blocks, which every PNG
// decoder accepts. Files are larger than compressed ones, which is fine for snapshots.
#include "eyesim/render/scene_renderer.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>

namespace eyesim::render {
namespace {

/// CRC-32 (ISO-HDLC, reflected 0xEDB88320) as PNG chunks require.
class Crc32 {
public:
    Crc32() {
        for (uint32_t i = 0; i < 256; ++i) {
            uint32_t c = i;
            for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
            table_[i] = c;
        }
    }
    uint32_t update(uint32_t crc, const uint8_t* p, size_t n) const {
        crc = ~crc;
        for (size_t i = 0; i < n; ++i) crc = table_[(crc ^ p[i]) & 0xFFu] ^ (crc >> 8);
        return ~crc;
    }

private:
    std::array<uint32_t, 256> table_{};
};

void put_be32(std::vector<uint8_t>& out, uint32_t v) {
    out.push_back(static_cast<uint8_t>(v >> 24));
    out.push_back(static_cast<uint8_t>(v >> 16));
    out.push_back(static_cast<uint8_t>(v >> 8));
    out.push_back(static_cast<uint8_t>(v));
}

void put_chunk(std::vector<uint8_t>& out, const char type[4], const std::vector<uint8_t>& data, const Crc32& crc) {
    put_be32(out, static_cast<uint32_t>(data.size()));
    const size_t type_at = out.size();
    out.insert(out.end(), type, type + 4);
    out.insert(out.end(), data.begin(), data.end());
    put_be32(out, crc.update(0, out.data() + type_at, 4 + data.size()));
}

}  // namespace

bool write_png(const std::string& path, int w, int h, const uint8_t* rgba, std::string& error) {
    if (w <= 0 || h <= 0 || rgba == nullptr) {
        error = path + ": invalid image (" + std::to_string(w) + "x" + std::to_string(h) + ")";
        return false;
    }
    const size_t row_bytes = static_cast<size_t>(w) * 4 + 1;  // filter byte + RGBA
    const size_t raw_size = row_bytes * static_cast<size_t>(h);

    // zlib stream: header, stored deflate blocks of at most 65535 bytes, Adler-32 of the raw data.
    std::vector<uint8_t> z;
    z.reserve(raw_size + raw_size / 65535 * 5 + 16);
    z.push_back(0x78);
    z.push_back(0x01);
    uint32_t a = 1, b = 0;
    std::vector<uint8_t> raw(raw_size);
    for (int y = 0; y < h; ++y) {
        uint8_t* row = raw.data() + static_cast<size_t>(y) * row_bytes;
        row[0] = 0;  // filter: none
        std::memcpy(row + 1, rgba + static_cast<size_t>(y) * static_cast<size_t>(w) * 4, row_bytes - 1);
    }
    for (size_t i = 0; i < raw_size; ++i) {
        a = (a + raw[i]) % 65521u;
        b = (b + a) % 65521u;
    }
    for (size_t at = 0; at < raw_size;) {
        const size_t n = std::min<size_t>(65535, raw_size - at);
        const bool last = at + n == raw_size;
        z.push_back(last ? 1 : 0);
        z.push_back(static_cast<uint8_t>(n & 0xFF));
        z.push_back(static_cast<uint8_t>(n >> 8));
        z.push_back(static_cast<uint8_t>(~n & 0xFF));
        z.push_back(static_cast<uint8_t>((~n >> 8) & 0xFF));
        z.insert(z.end(), raw.begin() + static_cast<std::ptrdiff_t>(at),
                 raw.begin() + static_cast<std::ptrdiff_t>(at + n));
        at += n;
    }
    put_be32(z, (b << 16) | a);

    const Crc32 crc;
    std::vector<uint8_t> file = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
    std::vector<uint8_t> ihdr;
    put_be32(ihdr, static_cast<uint32_t>(w));
    put_be32(ihdr, static_cast<uint32_t>(h));
    ihdr.insert(ihdr.end(), {8, 6, 0, 0, 0});  // 8 bits, RGBA, deflate, adaptive filters, no interlace
    put_chunk(file, "IHDR", ihdr, crc);
    put_chunk(file, "IDAT", z, crc);
    put_chunk(file, "IEND", {}, crc);

    std::FILE* f = std::fopen(path.c_str(), "wb");
    if (f == nullptr) {
        error = path + ": cannot open for writing: " + std::strerror(errno);
        return false;
    }
    const bool ok = std::fwrite(file.data(), 1, file.size(), f) == file.size();
    const bool closed = std::fclose(f) == 0;
    if (!ok || !closed) {
        error = path + ": write failed";
        return false;
    }
    return true;
}

bool write_side_by_side_png(const std::string& path, const StereoImages& img, std::string& error) {
    const size_t view_bytes = static_cast<size_t>(img.width) * static_cast<size_t>(img.height) * 4;
    if (img.width <= 0 || img.height <= 0 || img.left_rgba.size() != view_bytes ||
        img.right_rgba.size() != view_bytes) {
        error = path + ": stereo images are empty or their buffers do not match " + std::to_string(img.width) +
                "x" + std::to_string(img.height);
        return false;
    }
    const size_t row = static_cast<size_t>(img.width) * 4;
    std::vector<uint8_t> both(view_bytes * 2);
    for (int y = 0; y < img.height; ++y) {
        const size_t src = static_cast<size_t>(y) * row;
        std::memcpy(both.data() + src * 2, img.left_rgba.data() + src, row);
        std::memcpy(both.data() + src * 2 + row, img.right_rgba.data() + src, row);
    }
    return write_png(path, img.width * 2, img.height, both.data(), error);
}

}  // namespace eyesim::render
