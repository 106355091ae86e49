#include "eyesim/protocol/capture.hpp"

#include "eyesim/protocol/crc32c.hpp"
#include "wire_io.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <system_error>

namespace eyesim::protocol {

using namespace wire;

namespace {

void put_file_header(std::uint8_t* h, std::uint16_t version = kCaptureVersion) noexcept {
    std::memcpy(h, kCaptureMagic.data(), kCaptureMagic.size());
    put_u16(h + 8, version);
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

// Payload length of the record whose 12-byte header is `h` when the header is plausible (length 1..16384,
// direction 0, or 1 in version 2, the whole record within the `room` bytes left in the file), else 0. The CRC is
// checked separately.
std::size_t plausible_length(const std::uint8_t* h, std::uint64_t room, std::uint16_t version) noexcept {
    const std::size_t len = get_u16(h);
    const std::uint16_t direction = get_u16(h + 2);
    if (len == 0 || len > kMaxCaptureRecordBytes || direction > (version >= 2 ? 1 : 0)) return 0;
    return kCaptureRecordHeaderBytes + len + kCaptureRecordCrcBytes <= room ? len : 0;
}

// The CRC of a whole record (header and payload, then the CRC) read into `r`.
bool crc_matches(const std::uint8_t* r, std::size_t len) noexcept {
    return get_u32(r + kCaptureRecordHeaderBytes + len) == crc32c({r, kCaptureRecordHeaderBytes + len});
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------

const char* to_string(CaptureOpenError e) noexcept {
    switch (e) {
        case CaptureOpenError::None: return "none";
        case CaptureOpenError::CannotOpen: return "cannot_open";
        case CaptureOpenError::ShortHeader: return "short_header";
        case CaptureOpenError::UnsupportedVersion: return "unsupported_version";
        case CaptureOpenError::BadHeaderSize: return "bad_header_size";
    }
    return "unknown";
}

bool CaptureReader::fail_open(CaptureOpenError e, std::uint64_t header_bytes_read) noexcept {
    const int saved_errno = errno;
    close();
    open_error_ = e;
    char* m = open_message_.data();
    const std::size_t cap = open_message_.size();
    switch (e) {
        case CaptureOpenError::None: m[0] = '\0'; break;
        case CaptureOpenError::CannotOpen:
            std::snprintf(m, cap, "cannot open for reading: %s", std::strerror(saved_errno));
            break;
        case CaptureOpenError::ShortHeader:
            std::snprintf(m, cap, "capture file header truncated (%llu of %zu bytes)",
                          static_cast<unsigned long long>(header_bytes_read), kCaptureHeaderBytes);
            break;
        case CaptureOpenError::UnsupportedVersion:
            std::snprintf(m, cap, "capture format version %u not supported (this build reads %u to %u)",
                          static_cast<unsigned>(found_version_), static_cast<unsigned>(kCaptureOldestVersion),
                          static_cast<unsigned>(kCaptureVersion));
            break;
        case CaptureOpenError::BadHeaderSize:
            std::snprintf(m, cap, "capture header size %u not supported (this build reads %zu)",
                          static_cast<unsigned>(found_header_bytes_), kCaptureHeaderBytes);
            break;
    }
    return false;
}

bool CaptureReader::open(const char* path) noexcept {
    close();
    open_error_ = CaptureOpenError::None;
    open_message_[0] = '\0';
    found_version_ = found_header_bytes_ = 0;
    errno = 0;
    f_ = std::fopen(path, "rb");
    if (!f_) return fail_open(CaptureOpenError::CannotOpen, 0);
    size_ = file_size(f_);
    std::uint8_t h[kCaptureHeaderBytes] = {};
    const std::size_t got = std::fread(h, 1, sizeof h, f_);
    if (got == 0 && std::ferror(f_)) return fail_open(CaptureOpenError::CannotOpen, 0);  // e.g. a directory
    if (has_magic(h, got)) {
        if (got < kCaptureHeaderBytes) return fail_open(CaptureOpenError::ShortHeader, got);
        found_version_ = get_u16(h + 8);
        found_header_bytes_ = get_u16(h + 10);
        if (found_version_ < kCaptureOldestVersion || found_version_ > kCaptureVersion)
            return fail_open(CaptureOpenError::UnsupportedVersion, got);
        if (found_header_bytes_ != kCaptureHeaderBytes) return fail_open(CaptureOpenError::BadHeaderSize, got);
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
    offset_ = size_ = dropped_ = bad_offset_ = last_skipped_ = corrupt_regions_ = corrupt_bytes_ = 0;
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
        rec = CaptureRecord{0, false, CaptureDirection::Received, offset_, {buf_.data(), got}};
        offset_ += got;
        return CaptureStatus::Ok;
    }
    const std::uint64_t left = size_ > offset_ ? size_ - offset_ : 0;
    if (left == 0) {
        done_ = true;
        return CaptureStatus::End;
    }
    // A record that fails a check: scan on to the next good record (Corrupt, reading goes on there) or, when
    // none follows, treat the rest as a torn tail (a crash mid-write leaves exactly that).
    auto damaged = [&]() {
        const std::uint64_t next_good = resync_from(offset_ + 1);
        bad_offset_ = offset_;
        if (next_good >= size_) {
            done_ = true;
            dropped_ = left;
            return CaptureStatus::Torn;
        }
        last_skipped_ = next_good - offset_;
        ++corrupt_regions_;
        corrupt_bytes_ += last_skipped_;
        offset_ = next_good;
        if (std::fseek(f_, static_cast<long>(offset_), SEEK_SET) != 0) {
            done_ = true;
            return CaptureStatus::IoError;
        }
        return CaptureStatus::Corrupt;
    };
    if (left < kCaptureRecordHeaderBytes + 1 + kCaptureRecordCrcBytes) return damaged();
    if (std::fread(buf_.data(), 1, kCaptureRecordHeaderBytes, f_) != kCaptureRecordHeaderBytes) {
        done_ = true;
        return CaptureStatus::IoError;
    }
    const std::size_t len = plausible_length(buf_.data(), left, found_version_);
    if (len == 0) return damaged();
    const std::size_t rest = len + kCaptureRecordCrcBytes;
    if (std::fread(buf_.data() + kCaptureRecordHeaderBytes, 1, rest, f_) != rest) {
        done_ = true;
        return CaptureStatus::IoError;
    }
    if (!crc_matches(buf_.data(), len)) return damaged();
    rec = CaptureRecord{get_u64(buf_.data() + 4), true, static_cast<CaptureDirection>(get_u16(buf_.data() + 2)), offset_,
                        {buf_.data() + kCaptureRecordHeaderBytes, len}};
    offset_ += kCaptureRecordHeaderBytes + rest;
    return CaptureStatus::Ok;
}

std::size_t CaptureReader::read_record_at(std::uint64_t at) noexcept {
    if (at > size_ || std::fseek(f_, static_cast<long>(at), SEEK_SET) != 0) return 0;
    if (std::fread(buf_.data(), 1, kCaptureRecordHeaderBytes, f_) != kCaptureRecordHeaderBytes) return 0;
    const std::size_t len = plausible_length(buf_.data(), size_ - at, found_version_);
    if (len == 0) return 0;
    const std::size_t rest = len + kCaptureRecordCrcBytes;
    if (std::fread(buf_.data() + kCaptureRecordHeaderBytes, 1, rest, f_) != rest) return 0;
    return crc_matches(buf_.data(), len) ? len : 0;
}

std::uint64_t CaptureReader::resync_from(std::uint64_t from) noexcept {
    // Headers are screened in a window (length in range, direction valid, fits the file); only a plausible one costs
    // a read and a CRC. A false match needs a 32-bit CRC to agree as well.
    constexpr std::uint64_t kMinRecord = kCaptureRecordHeaderBytes + 1 + kCaptureRecordCrcBytes;
    if (size_ < kMinRecord) return size_;
    const std::uint64_t last = size_ - kMinRecord;  // last offset a record can start at
    std::uint64_t p = from;
    while (p <= last) {
        const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(scan_.size(), size_ - p));
        if (std::fseek(f_, static_cast<long>(p), SEEK_SET) != 0 || std::fread(scan_.data(), 1, n, f_) != n)
            return size_;
        const std::size_t candidates = n - kCaptureRecordHeaderBytes + 1;  // headers wholly in the window
        for (std::size_t i = 0; i < candidates && p + i <= last; ++i)
            if (plausible_length(scan_.data() + i, size_ - (p + i), found_version_) != 0 && read_record_at(p + i) != 0) return p + i;
        p += candidates;
    }
    return size_;
}

// ---------------------------------------------------------------------------------------------------------------

bool CaptureWriter::create(const char* path) noexcept {
    close();
    recovered_ = dropped_ = 0;
    version_ = kCaptureVersion;
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
            std::uint8_t want[kCaptureHeaderBytes], want_v1[kCaptureHeaderBytes];
            put_file_header(want);
            put_file_header(want_v1, kCaptureOldestVersion);
            if (got >= kCaptureHeaderBytes || (std::memcmp(h, want, got) != 0 && std::memcmp(h, want_v1, got) != 0))
                return false;
            dropped_ = got;
            return create(path);
        }
        CaptureRecord rec;
        CaptureStatus s;
        good_end = kCaptureHeaderBytes;
        while ((s = reader.next(rec)) == CaptureStatus::Ok || s == CaptureStatus::Corrupt) {
            if (s == CaptureStatus::Corrupt) continue;  // damaged stretches between good records stay
            ++recovered_;
            good_end = rec.file_offset + kCaptureRecordHeaderBytes + rec.bytes.size() + kCaptureRecordCrcBytes;
        }
        if (s == CaptureStatus::IoError) return false;
        dropped_ = reader.dropped_bytes();
        version_ = reader.found_format_version();  // an older file keeps its format (no Sent records then)
    }
    if (dropped_ > 0) {
        std::error_code ec;
        std::filesystem::resize_file(path, good_end, ec);
        if (ec) return false;
    }
    f_ = std::fopen(path, "ab");
    return f_ != nullptr;
}

bool CaptureWriter::write(std::uint64_t host_us, std::span<const std::uint8_t> bytes,
                          CaptureDirection direction) noexcept {
    if (!f_ || bytes.empty() || bytes.size() > kMaxCaptureRecordBytes) return false;
    if (direction != CaptureDirection::Received && version_ < 2) return false;
    std::uint8_t h[kCaptureRecordHeaderBytes];
    put_u16(h, static_cast<std::uint16_t>(bytes.size()));
    put_u16(h + 2, static_cast<std::uint16_t>(direction));
    put_u64(h + 4, host_us);
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
