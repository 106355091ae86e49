// libFuzzer target for the capture reader. The first input byte picks a mode:
//   even: the rest follows a capture file header as is (any bytes: damaged files, garbage);
//   odd:  the rest is a list of records (control byte, length, payload) written with correct headers and CRCs,
//         or runs of zeros (control bit 6), followed by (offset, mask) byte flips, so the fuzzer reaches good
//         records behind damage of any length.
// The file is read back with CaptureReader and every status it returns is checked against a plain reference
// scan over the bytes in memory (a record is good where its header, bounds and CRC check out; after a bad one,
// reading goes on at the next offset that holds a good record). Any disagreement aborts.
#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/crc32c.hpp"
#include "fuzz_require.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

namespace {

using namespace eyesim::protocol;

std::uint16_t u16(const std::vector<std::uint8_t>& b, std::size_t at) {
    return static_cast<std::uint16_t>(b[at] | b[at + 1] << 8);
}
std::uint32_t u32(const std::vector<std::uint8_t>& b, std::size_t at) {
    return static_cast<std::uint32_t>(b[at]) | static_cast<std::uint32_t>(b[at + 1]) << 8 |
           static_cast<std::uint32_t>(b[at + 2]) << 16 | static_cast<std::uint32_t>(b[at + 3]) << 24;
}

struct Event {
    CaptureStatus status;
    std::uint64_t offset;  // record offset (Ok) or bad offset (Corrupt, Torn)
    std::uint64_t bytes;   // payload bytes (Ok), skipped bytes (Corrupt), dropped bytes (Torn)
    bool operator==(const Event& o) const { return status == o.status && offset == o.offset && bytes == o.bytes; }
};

bool good_at(const std::vector<std::uint8_t>& f, std::size_t p) {
    if (p + kCaptureRecordHeaderBytes + 1 + kCaptureRecordCrcBytes > f.size()) return false;
    const std::size_t len = u16(f, p);
    if (len == 0 || len > kMaxCaptureRecordBytes || u16(f, p + 2) != 0) return false;
    if (p + kCaptureRecordHeaderBytes + len + kCaptureRecordCrcBytes > f.size()) return false;
    return crc32c({f.data() + p, kCaptureRecordHeaderBytes + len}) == u32(f, p + kCaptureRecordHeaderBytes + len);
}

std::vector<Event> reference(const std::vector<std::uint8_t>& f) {
    std::vector<Event> out;
    std::size_t p = kCaptureHeaderBytes;
    while (p < f.size()) {
        if (good_at(f, p)) {
            const std::size_t len = u16(f, p);
            out.push_back({CaptureStatus::Ok, p, len});
            p += kCaptureRecordHeaderBytes + len + kCaptureRecordCrcBytes;
            continue;
        }
        std::size_t q = p + 1;
        while (q < f.size() && !good_at(f, q)) ++q;
        if (q >= f.size()) {
            out.push_back({CaptureStatus::Torn, p, f.size() - p});
            return out;
        }
        out.push_back({CaptureStatus::Corrupt, p, q - p});
        p = q;
    }
    out.push_back({CaptureStatus::End, 0, 0});
    return out;
}

void put_record(std::vector<std::uint8_t>& f, std::uint64_t t, const std::uint8_t* payload, std::size_t len) {
    const std::size_t at = f.size();
    f.push_back(static_cast<std::uint8_t>(len));
    f.push_back(static_cast<std::uint8_t>(len >> 8));
    f.push_back(0);
    f.push_back(0);
    for (int i = 0; i < 8; ++i) f.push_back(static_cast<std::uint8_t>(t >> (8 * i)));
    f.insert(f.end(), payload, payload + len);
    const std::uint32_t c = crc32c({f.data() + at, kCaptureRecordHeaderBytes + len});
    for (int i = 0; i < 4; ++i) f.push_back(static_cast<std::uint8_t>(c >> (8 * i)));
}

// One scratch file per process, removed at exit.
struct TempFile {
    std::string path = "/tmp/eyesim_fuzz_capture_" + std::to_string(::getpid()) + ".cap";
    ~TempFile() { std::remove(path.c_str()); }
};
const std::string& temp_path() {
    static const TempFile file;
    return file.path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size < 1) return 0;
    std::vector<std::uint8_t> f = {'E', 'Y', 'E', 'S', 'I', 'M', 'C', 'P', 1, 0, 16, 0, 0, 0, 0, 0};
    if ((data[0] & 1) == 0) {
        f.insert(f.end(), data + 1, data + size);
    } else {
        std::size_t i = 1;
        std::uint64_t t = 0;
        // Records while the control byte's top bit is clear; then flips (2 offset bytes, 1 mask).
        while (i + 3 <= size && (data[i] & 0x80) == 0) {
            const std::size_t len = 1 + (static_cast<std::size_t>(data[i + 1]) | static_cast<std::size_t>(data[i + 2] & 0x3F) << 8);
            const bool gap = (data[i] & 0x40) != 0;
            i += 3;
            if (gap) {  // a run of zero bytes (never a plausible header): long resyncs across the scan window
                f.insert(f.end(), len, std::uint8_t{0});
                continue;
            }
            const std::size_t take = std::min(len, size - i);
            if (take == 0) break;
            put_record(f, t += 1000, data + i, take);
            i += take;
        }
        if (i < size) ++i;
        for (; i + 3 <= size; i += 3) {
            const std::size_t at = kCaptureHeaderBytes + (static_cast<std::size_t>(data[i]) | static_cast<std::size_t>(data[i + 1]) << 8);
            if (at < f.size()) f[at] ^= data[i + 2];
        }
    }
    {
        std::FILE* out = std::fopen(temp_path().c_str(), "wb");
        require(out != nullptr);
        require(std::fwrite(f.data(), 1, f.size(), out) == f.size());
        std::fclose(out);
    }
    auto reader = std::make_unique<CaptureReader>();
    require(reader->open(temp_path().c_str()));
    require(reader->kind() == CaptureKind::Capture);
    std::vector<Event> got;
    CaptureRecord rec;
    for (;;) {
        const CaptureStatus s = reader->next(rec);
        if (s == CaptureStatus::Ok) {
            require(rec.has_time);
            require(rec.file_offset + kCaptureRecordHeaderBytes + rec.bytes.size() <= f.size());
            for (std::size_t k = 0; k < rec.bytes.size(); ++k)
                require(rec.bytes[k] == f[rec.file_offset + kCaptureRecordHeaderBytes + k]);
            got.push_back({s, rec.file_offset, rec.bytes.size()});
        } else if (s == CaptureStatus::Corrupt) {
            got.push_back({s, reader->bad_offset(), reader->last_skipped_bytes()});
        } else if (s == CaptureStatus::Torn) {
            got.push_back({s, reader->bad_offset(), reader->dropped_bytes()});
            break;
        } else {
            require(s == CaptureStatus::End);
            got.push_back({s, 0, 0});
            break;
        }
        require(got.size() <= f.size());  // every status consumes bytes: no endless loop
    }
    require(reader->next(rec) == CaptureStatus::End);  // stays ended
    require(got == reference(f));
    return 0;
}
