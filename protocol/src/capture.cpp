#include "eyesim/protocol/capture.hpp"

#include "eyesim/protocol/crc32c.hpp"
#include "wire_io.hpp"

#include <cstring>
#include <filesystem>
#include <system_error>

namespace eyesim::protocol {

using namespace wire;

namespace {

void put_file_header(std::uint8_t* h) noexcept {
    std::memcpy(h, kCaptureMagic.data(), kCaptureMagic.size());
    put_u16(h + 8, kCaptureVersion);
    put_u16(h + 10, static_cast<std::uint16_t>(kCaptureHeaderBytes));
    put_u32(h + 12, 0);
}

bool has_magic(const std::uint8_t* h, std::size_t n) noexcept {
    return n >= kCaptureMagic.size() && std::memcmp(h, kCaptureMagic.data(), kCaptureMagic.size()) == 0;
}

std::uint64_t file_size(std::FILE* f) noexcept {
    if (std::fseek(f, 0, SEEK_END) != 0) return 0;
    const long s = std::ftell(f);
    std::fseek(f, 0, SEEK_SET);
    return s < 0 ? 0 : static_cast<std::uint64_t>(s);
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------

bool CaptureReader::open(const char* path) noexcept {
    close();
    f_ = std::fopen(path, "rb");
    if (!f_) return false;
    size_ = file_size(f_);
    std::uint8_t h[kCaptureHeaderBytes] = {};
    const std::size_t got = std::fread(h, 1, sizeof h, f_);
    if (has_magic(h, got)) {
        if (got < kCaptureHeaderBytes || get_u16(h + 8) != kCaptureVersion ||
            get_u16(h + 10) != kCaptureHeaderBytes) {
            close();
            return false;
        }
        kind_ = CaptureKind::Capture;
        offset_ = kCaptureHeaderBytes;
    } else {
        kind_ = CaptureKind::RawStream;
        offset_ = 0;
        std::fseek(f_, 0, SEEK_SET);
    }
    return true;
}

void CaptureReader::close() noexcept {
    if (f_) std::fclose(f_);
    f_ = nullptr;
    offset_ = size_ = dropped_ = bad_offset_ = 0;
    done_ = false;
}

CaptureStatus CaptureReader::next(CaptureRecord& rec) noexcept {
    if (!f_ || done_) return CaptureStatus::End;
    if (kind_ == CaptureKind::RawStream) {
        const std::size_t got = std::fread(buf_.data(), 1, kMaxCaptureRecordBytes, f_);
        if (got == 0) {
            done_ = true;
            return std::ferror(f_) ? CaptureStatus::IoError : CaptureStatus::End;
        }
        rec = CaptureRecord{0, false, offset_, {buf_.data(), got}};
        offset_ += got;
        return CaptureStatus::Ok;
    }
    const std::uint64_t left = size_ > offset_ ? size_ - offset_ : 0;
    if (left == 0) {
        done_ = true;
        return CaptureStatus::End;
    }
    auto stop = [&](CaptureStatus s) {
        done_ = true;
        bad_offset_ = offset_;
        dropped_ = left;
        return s;
    };
    if (left < kCaptureRecordHeaderBytes + 1 + kCaptureRecordCrcBytes) return stop(CaptureStatus::Torn);
    if (std::fread(buf_.data(), 1, kCaptureRecordHeaderBytes, f_) != kCaptureRecordHeaderBytes)
        return stop(CaptureStatus::IoError);
    const std::size_t len = get_u16(buf_.data());
    const std::size_t total = kCaptureRecordHeaderBytes + len + kCaptureRecordCrcBytes;
    if (len == 0 || len > kMaxCaptureRecordBytes || get_u16(buf_.data() + 2) != 0)
        return stop(total >= left ? CaptureStatus::Torn : CaptureStatus::Corrupt);
    if (total > left) return stop(CaptureStatus::Torn);
    const std::size_t rest = len + kCaptureRecordCrcBytes;
    if (std::fread(buf_.data() + kCaptureRecordHeaderBytes, 1, rest, f_) != rest) return stop(CaptureStatus::IoError);
    const std::uint32_t crc = get_u32(buf_.data() + kCaptureRecordHeaderBytes + len);
    if (crc != crc32c({buf_.data(), kCaptureRecordHeaderBytes + len}))
        return stop(total == left ? CaptureStatus::Torn : CaptureStatus::Corrupt);
    rec = CaptureRecord{get_u64(buf_.data() + 4), true, offset_, {buf_.data() + kCaptureRecordHeaderBytes, len}};
    offset_ += total;
    return CaptureStatus::Ok;
}

// ---------------------------------------------------------------------------------------------------------------

bool CaptureWriter::create(const char* path) noexcept {
    close();
    recovered_ = dropped_ = 0;
    f_ = std::fopen(path, "wb");
    if (!f_) return false;
    std::uint8_t h[kCaptureHeaderBytes];
    put_file_header(h);
    if (std::fwrite(h, 1, sizeof h, f_) != sizeof h || std::fflush(f_) != 0) {
        close();
        return false;
    }
    return true;
}

bool CaptureWriter::append(const char* path) noexcept {
    close();
    recovered_ = dropped_ = 0;
    std::uint64_t good_end = 0;
    {
        std::FILE* probe = std::fopen(path, "rb");
        if (!probe) return create(path);
        std::fclose(probe);
        CaptureReader reader;
        if (!reader.open(path)) return false;
        if (reader.kind() != CaptureKind::Capture) {
            // Empty or a header torn by a crash: nothing to keep. Anything else is not ours to overwrite.
            std::uint8_t h[kCaptureHeaderBytes];
            put_file_header(h);
            std::FILE* f = std::fopen(path, "rb");
            const std::size_t got = f ? std::fread(h, 1, sizeof h, f) : 0;
            if (f) std::fclose(f);
            std::uint8_t want[kCaptureHeaderBytes];
            put_file_header(want);
            if (got >= kCaptureHeaderBytes || std::memcmp(h, want, got) != 0) return false;
            dropped_ = got;
            return create(path);
        }
        CaptureRecord rec;
        CaptureStatus s;
        good_end = kCaptureHeaderBytes;
        while ((s = reader.next(rec)) == CaptureStatus::Ok) {
            ++recovered_;
            good_end = rec.file_offset + kCaptureRecordHeaderBytes + rec.bytes.size() + kCaptureRecordCrcBytes;
        }
        if (s == CaptureStatus::IoError) return false;
        dropped_ = reader.dropped_bytes();
    }
    if (dropped_ > 0) {
        std::error_code ec;
        std::filesystem::resize_file(path, good_end, ec);
        if (ec) return false;
    }
    f_ = std::fopen(path, "ab");
    return f_ != nullptr;
}

bool CaptureWriter::write(std::uint64_t host_rx_us, std::span<const std::uint8_t> bytes) noexcept {
    if (!f_ || bytes.empty() || bytes.size() > kMaxCaptureRecordBytes) return false;
    std::uint8_t h[kCaptureRecordHeaderBytes];
    put_u16(h, static_cast<std::uint16_t>(bytes.size()));
    put_u16(h + 2, 0);
    put_u64(h + 4, host_rx_us);
    std::uint8_t c[kCaptureRecordCrcBytes];
    put_u32(c, crc32c_finish(crc32c_update(crc32c_update(kCrc32cInit, h), bytes)));
    if (std::fwrite(h, 1, sizeof h, f_) != sizeof h || std::fwrite(bytes.data(), 1, bytes.size(), f_) != bytes.size() ||
        std::fwrite(c, 1, sizeof c, f_) != sizeof c)
        return false;
    return !flush_each_ || std::fflush(f_) == 0;
}

bool CaptureWriter::flush() noexcept { return f_ && std::fflush(f_) == 0; }

void CaptureWriter::close() noexcept {
    if (f_) std::fclose(f_);
    f_ = nullptr;
}

}  // namespace eyesim::protocol
