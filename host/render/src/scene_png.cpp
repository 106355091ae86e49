// PNG writing without zlib: per-row PNG filters, then one deflate block with the fixed Huffman codes and greedy
// LZ77 matching (RFC 1951). Not as small as zlib's best, but a few times smaller than raw pixels and deterministic.
#include "eyesim/render/scene_renderer.hpp"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdint>
#include <cstdlib>
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

uint32_t adler32(const std::vector<uint8_t>& data) {
    uint32_t a = 1, b = 0;
    for (uint8_t v : data) {
        a = (a + v) % 65521u;
        b = (b + a) % 65521u;
    }
    return (b << 16) | a;
}

uint8_t paeth(int a, int b, int c) {
    const int p = a + b - c, pa = std::abs(p - a), pb = std::abs(p - b), pc = std::abs(p - c);
    return static_cast<uint8_t>(pa <= pb && pa <= pc ? a : (pb <= pc ? b : c));
}

/// PNG scanlines with a filter byte each: per row the filter (none, sub, up, average, Paeth) whose output has the
/// smallest sum of absolute values (the heuristic the PNG specification recommends).
std::vector<uint8_t> filter_rows(int w, int h, const uint8_t* rgba) {
    const size_t stride = static_cast<size_t>(w) * 4;
    std::vector<uint8_t> out((stride + 1) * static_cast<size_t>(h));
    std::vector<uint8_t> zero(stride, 0), candidate(stride), best(stride);
    for (int y = 0; y < h; ++y) {
        const uint8_t* row = rgba + static_cast<size_t>(y) * stride;
        const uint8_t* up = y > 0 ? row - stride : zero.data();
        uint64_t best_cost = UINT64_MAX;
        uint8_t best_filter = 0;
        for (uint8_t f = 0; f < 5; ++f) {
            uint64_t cost = 0;
            for (size_t i = 0; i < stride; ++i) {
                const int a = i >= 4 ? row[i - 4] : 0, b = up[i], c = i >= 4 ? up[i - 4] : 0;
                int pred = 0;
                if (f == 1) pred = a;
                if (f == 2) pred = b;
                if (f == 3) pred = (a + b) / 2;
                if (f == 4) pred = paeth(a, b, c);
                candidate[i] = static_cast<uint8_t>(row[i] - pred);
                cost += static_cast<uint64_t>(std::abs(static_cast<int8_t>(candidate[i])));
            }
            if (cost < best_cost) {
                best_cost = cost;
                best_filter = f;
                best.swap(candidate);
            }
        }
        uint8_t* dst = out.data() + static_cast<size_t>(y) * (stride + 1);
        dst[0] = best_filter;
        std::memcpy(dst + 1, best.data(), stride);
    }
    return out;
}

/// Bits into bytes, least significant bit first (deflate's order).
class BitWriter {
public:
    explicit BitWriter(std::vector<uint8_t>& out) : out_(out) {}
    void put(uint32_t value, int bits) {
        acc_ |= static_cast<uint64_t>(value) << used_;
        used_ += bits;
        while (used_ >= 8) {
            out_.push_back(static_cast<uint8_t>(acc_ & 0xFFu));
            acc_ >>= 8;
            used_ -= 8;
        }
    }
    /// A Huffman code: sent most significant bit first.
    void put_code(uint32_t code, int bits) {
        uint32_t r = 0;
        for (int i = 0; i < bits; ++i) r |= ((code >> i) & 1u) << (bits - 1 - i);
        put(r, bits);
    }
    void flush() {
        if (used_ > 0) out_.push_back(static_cast<uint8_t>(acc_ & 0xFFu));
        acc_ = 0;
        used_ = 0;
    }

private:
    std::vector<uint8_t>& out_;
    uint64_t acc_ = 0;
    int used_ = 0;
};

/// Literal/length symbol with the fixed Huffman code of RFC 1951 §3.2.6.
void put_fixed_symbol(BitWriter& bw, int sym) {
    if (sym < 144) bw.put_code(static_cast<uint32_t>(0x30 + sym), 8);
    else if (sym < 256) bw.put_code(static_cast<uint32_t>(0x190 + sym - 144), 9);
    else if (sym < 280) bw.put_code(static_cast<uint32_t>(sym - 256), 7);
    else bw.put_code(static_cast<uint32_t>(0xC0 + sym - 280), 8);
}

constexpr std::array<uint16_t, 29> kLengthBase = {3,  4,  5,  6,  7,  8,  9,  10, 11,  13,  15,  17,  19,  23, 27,
                                                  31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258};
constexpr std::array<uint8_t, 29> kLengthExtra = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2,
                                                  2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0};
constexpr std::array<uint16_t, 30> kDistBase = {1,   2,   3,   4,   5,   7,    9,    13,   17,   25,
                                                33,  49,  65,  97,  129, 193,  257,  385,  513,  769,
                                                1025, 1537, 2049, 3073, 4097, 6145, 8193, 12289, 16385, 24577};
constexpr std::array<uint8_t, 30> kDistExtra = {0, 0, 0, 0, 1, 1, 2, 2,  3,  3,  4,  4,  5,  5,  6,
                                                6, 7, 7, 8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13};

/// One final deflate block with the fixed Huffman codes and greedy LZ77 matches (hash chains over 3-byte prefixes,
/// 32 KiB window). Simple and deterministic; compresses the renderer's pictures several-fold.
void deflate_fixed(const std::vector<uint8_t>& in, std::vector<uint8_t>& out) {
    constexpr size_t kWindow = 32768, kMaxLen = 258, kMinLen = 3;
    constexpr int kHashBits = 15, kMaxChain = 32;
    BitWriter bw(out);
    bw.put(1, 1);  // BFINAL
    bw.put(1, 2);  // BTYPE = 01, fixed Huffman codes
    std::vector<int32_t> head(size_t(1) << kHashBits, -1), prev(in.size(), -1);
    auto hash = [&](size_t i) {
        const uint32_t v = uint32_t(in[i]) | uint32_t(in[i + 1]) << 8 | uint32_t(in[i + 2]) << 16;
        return (v * 2654435761u) >> (32 - kHashBits);
    };
    auto insert = [&](size_t i) {
        if (i + kMinLen > in.size()) return;
        const uint32_t hv = hash(i);
        prev[i] = head[hv];
        head[hv] = static_cast<int32_t>(i);
    };
    for (size_t i = 0; i < in.size();) {
        size_t best_len = 0, best_dist = 0;
        if (i + kMinLen <= in.size()) {
            const size_t limit = std::min(kMaxLen, in.size() - i);
            int32_t cand = head[hash(i)];
            for (int chain = 0; cand >= 0 && chain < kMaxChain; ++chain, cand = prev[size_t(cand)]) {
                const size_t c = static_cast<size_t>(cand);
                if (i - c > kWindow) break;
                size_t len = 0;
                while (len < limit && in[c + len] == in[i + len]) ++len;
                if (len > best_len) {
                    best_len = len;
                    best_dist = i - c;
                    if (len == limit) break;
                }
            }
        }
        if (best_len >= kMinLen) {
            size_t li = kLengthBase.size() - 1;
            while (kLengthBase[li] > best_len) --li;
            put_fixed_symbol(bw, static_cast<int>(257 + li));
            bw.put(static_cast<uint32_t>(best_len - kLengthBase[li]), kLengthExtra[li]);
            size_t di = kDistBase.size() - 1;
            while (kDistBase[di] > best_dist) --di;
            bw.put_code(static_cast<uint32_t>(di), 5);
            bw.put(static_cast<uint32_t>(best_dist - kDistBase[di]), kDistExtra[di]);
            for (size_t k = 0; k < best_len; ++k) insert(i + k);
            i += best_len;
        } else {
            put_fixed_symbol(bw, in[i]);
            insert(i);
            ++i;
        }
    }
    put_fixed_symbol(bw, 256);  // end of block
    bw.flush();
}

}  // namespace

bool write_png(const std::string& path, int w, int h, const uint8_t* rgba, std::string& error) {
    if (w <= 0 || h <= 0 || rgba == nullptr) {
        error = path + ": invalid image (" + std::to_string(w) + "x" + std::to_string(h) + ")";
        return false;
    }
    const std::vector<uint8_t> raw = filter_rows(w, h, rgba);
    std::vector<uint8_t> z = {0x78, 0x01};  // zlib header: deflate, 32 KiB window
    deflate_fixed(raw, z);
    put_be32(z, adler32(raw));

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
