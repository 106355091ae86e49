#pragma once
/// \file
/// Capture files: the received bytes with their host receive timestamps, appendable, and readable after a crash
/// mid-write (a torn last record is reported and skipped, all earlier records survive). Layout (little-endian):
///
///   file header, 16 bytes: magic "EYESIMCP" (8), u16 format version 2, u16 header bytes 16, u32 reserved 0
///   record: u16 length L (1..kMaxCaptureRecordBytes), u16 direction (0 received by the host, 1 sent by the host;
///           always 0 in version 1), u64 host time µs, L bytes, u32 CRC-32C over the 12 header bytes and the L bytes
///
/// The host's own commands are recorded too (direction 1), so a capture holds the register reads and writes and
/// their replies: the device's register map can be rebuilt from it.
///
/// A record normally holds one frame; it may hold any received chunk (the reader feeds it to a StreamParser).
/// A damaged record in the middle of a file is skipped: the reader scans on to the next offset that holds a whole
/// record with a good CRC and goes on from there, so one bad byte costs one record, not the rest of the file.
/// A file that does not start with the magic is read as a raw byte stream (chunks without timestamps).
/// Host-side code: uses stdio (the codec and parser stay heap-free), never throws.

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <span>

namespace eyesim::protocol {

/// Capture file magic, the first 8 bytes.
inline constexpr std::array<std::uint8_t, 8> kCaptureMagic = {'E', 'Y', 'E', 'S', 'I', 'M', 'C', 'P'};
/// Capture format version written (2: records carry a direction). Readers also read version 1.
inline constexpr std::uint16_t kCaptureVersion = 2;
/// Oldest capture format version readers accept (1: every record was received by the host).
inline constexpr std::uint16_t kCaptureOldestVersion = 1;
/// Capture file header bytes.
inline constexpr std::size_t kCaptureHeaderBytes = 16;
/// Who produced a record's bytes.
enum class CaptureDirection : std::uint16_t {
    Received = 0,  ///< bytes the host received from the device
    Sent = 1,      ///< bytes the host sent to the device (its commands)
};

/// Record header bytes (length, direction, host time).
inline constexpr std::size_t kCaptureRecordHeaderBytes = 12;
/// Record trailer bytes (CRC-32C).
inline constexpr std::size_t kCaptureRecordCrcBytes = 4;
/// Largest record payload.
inline constexpr std::size_t kMaxCaptureRecordBytes = 16384;

/// One record as read back.
struct CaptureRecord {
    std::uint64_t host_rx_us = 0;            ///< host receive time, µs (0 for raw streams)
    bool has_time = false;                   ///< false for chunks of a raw byte stream
    CaptureDirection direction = CaptureDirection::Received;  ///< Sent: the host's own commands
    std::uint64_t file_offset = 0;           ///< offset of the record (or chunk) in the file
    std::span<const std::uint8_t> bytes;     ///< the received bytes; valid until the next read
};

/// Outcome of CaptureReader::next().
enum class CaptureStatus : std::uint8_t {
    Ok,       ///< a record was read
    End,      ///< clean end of file
    Torn,     ///< the file ends in a damaged or incomplete record (no good record follows it; skipped, reading ends)
    Corrupt,  ///< damaged bytes [bad_offset(), + last_skipped_bytes()) were skipped and a good record follows:
              ///< call next() again for it (not terminal)
    IoError,  ///< read error
};

/// Why CaptureReader::open() failed.
enum class CaptureOpenError : std::uint8_t {
    None,                ///< opened (or not tried yet)
    CannotOpen,          ///< the file cannot be opened for reading (missing, no permission, a directory, ...)
    ShortHeader,         ///< it starts with the capture magic but ends inside the 16-byte file header
    UnsupportedVersion,  ///< its format_version is not 1 or 2 (found_format_version() says which)
    BadHeaderSize,       ///< its header_bytes is not kCaptureHeaderBytes (found_header_bytes() says which)
};

/// Short name of an open error ("none", "cannot_open", "short_header", "unsupported_version", "bad_header_size").
const char* to_string(CaptureOpenError e) noexcept;

/// What kind of file a reader opened.
enum class CaptureKind : std::uint8_t {
    Capture,    ///< "EYESIMCP" capture file
    RawStream,  ///< any other file: a raw byte stream
};

/// Reads a capture file (or a raw byte stream) record by record without allocating per record.
class CaptureReader {
public:
    CaptureReader() = default;
    CaptureReader(const CaptureReader&) = delete;
    CaptureReader& operator=(const CaptureReader&) = delete;
    ~CaptureReader() { close(); }

    /// Opens `path`; false when it cannot be opened or has a capture magic with an unsupported version/header
    /// (open_error() and open_error_message() say why).
    bool open(const char* path) noexcept;
    /// Why the last open() failed (None after a successful one).
    CaptureOpenError open_error() const noexcept { return open_error_; }
    /// The reason as one line without the path, e.g. "capture format version 7 not supported (this build reads
    /// 1)"; empty after a successful open().
    const char* open_error_message() const noexcept { return open_message_.data(); }
    /// format_version and header_bytes of the capture header the last open() read (0 when it read none).
    std::uint16_t found_format_version() const noexcept { return found_version_; }
    std::uint16_t found_header_bytes() const noexcept { return found_header_bytes_; }
    /// Size of the opened file in bytes.
    std::uint64_t file_bytes() const noexcept { return size_; }
    /// Closes the file.
    void close() noexcept;
    /// Capture or raw stream (valid after open()).
    CaptureKind kind() const noexcept { return kind_; }
    /// Reads the next record (raw streams: the next chunk of up to kMaxCaptureRecordBytes).
    CaptureStatus next(CaptureRecord& rec) noexcept;
    /// Bytes of the torn tail (after Torn; 0 otherwise).
    std::uint64_t dropped_bytes() const noexcept { return dropped_; }
    /// Offset where the last Torn or Corrupt stretch starts.
    std::uint64_t bad_offset() const noexcept { return bad_offset_; }
    /// Length of the stretch the last Corrupt status skipped.
    std::uint64_t last_skipped_bytes() const noexcept { return last_skipped_; }
    /// Damaged stretches skipped in the middle of the file so far, and their bytes (the torn tail not included).
    std::uint64_t corrupt_regions() const noexcept { return corrupt_regions_; }
    std::uint64_t corrupt_bytes() const noexcept { return corrupt_bytes_; }

private:
    std::FILE* f_ = nullptr;
    CaptureKind kind_ = CaptureKind::RawStream;
    std::uint64_t offset_ = 0;     // file offset of the next record
    std::uint64_t size_ = 0;       // file size at open()
    std::uint64_t dropped_ = 0;
    std::uint64_t bad_offset_ = 0;
    std::uint64_t last_skipped_ = 0;
    std::uint64_t corrupt_regions_ = 0;
    std::uint64_t corrupt_bytes_ = 0;
    bool done_ = false;
    CaptureOpenError open_error_ = CaptureOpenError::None;
    std::uint16_t found_version_ = 0;
    std::uint16_t found_header_bytes_ = 0;
    std::array<char, 128> open_message_{};
    bool fail_open(CaptureOpenError e, std::uint64_t header_bytes_read) noexcept;
    // Reads the record at `at` (whole, CRC checked) into buf_; its payload length, or 0 when none is there.
    std::size_t read_record_at(std::uint64_t at) noexcept;
    // First offset after `from` that holds a good record, or size_ when there is none.
    std::uint64_t resync_from(std::uint64_t from) noexcept;
    std::array<std::uint8_t, kCaptureRecordHeaderBytes + kMaxCaptureRecordBytes + kCaptureRecordCrcBytes> buf_{};
    std::array<std::uint8_t, 4096 + kCaptureRecordHeaderBytes> scan_{};  // header window for resync_from()
};

/// Writes capture files: creates a new one, or appends to an existing one after dropping its torn tail.
class CaptureWriter {
public:
    CaptureWriter() = default;
    CaptureWriter(const CaptureWriter&) = delete;
    CaptureWriter& operator=(const CaptureWriter&) = delete;
    ~CaptureWriter() { close(); }

    /// Creates (truncates) `path` and writes the file header.
    bool create(const char* path) noexcept;
    /// Opens `path` for appending: creates it if missing; otherwise checks the header, keeps every good record
    /// (damaged stretches between good records stay; readers skip them) and cuts a torn tail off (see
    /// recovered_records() / dropped_bytes()).
    bool append(const char* path) noexcept;
    /// Appends one record (1..kMaxCaptureRecordBytes bytes) and, with flush_each (default), flushes it to the OS.
    /// A Sent record cannot go into a version-1 file opened by append() (false; that format has no direction).
    bool write(std::uint64_t host_us, std::span<const std::uint8_t> bytes,
               CaptureDirection direction = CaptureDirection::Received) noexcept;
    /// Format version of the open file (kCaptureVersion unless append() kept an older file's).
    std::uint16_t format_version() const noexcept { return version_; }
    /// Flushes buffered records to the OS.
    bool flush() noexcept;
    /// Flushes and closes.
    void close() noexcept;
    /// Flush after every record (default true: a crash loses at most the record being written).
    void set_flush_each(bool on) noexcept { flush_each_ = on; }
    /// Good records found in the file by append().
    std::uint64_t recovered_records() const noexcept { return recovered_; }
    /// Bytes cut off a torn tail by append().
    std::uint64_t dropped_bytes() const noexcept { return dropped_; }

private:
    std::FILE* f_ = nullptr;
    bool flush_each_ = true;
    std::uint16_t version_ = kCaptureVersion;
    std::uint64_t recovered_ = 0;
    std::uint64_t dropped_ = 0;
};

}  // namespace eyesim::protocol
