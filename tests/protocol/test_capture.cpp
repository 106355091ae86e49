#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "test_util.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <filesystem>
#include <iterator>
#include <fstream>
#include <memory>
#include <string>

using namespace eyesim::protocol;
using namespace eyesim::protocol::test;
namespace fs = std::filesystem;

namespace {

struct Rec {
    std::uint64_t t;
    Bytes bytes;
    bool operator==(const Rec& o) const { return t == o.t && bytes == o.bytes; }
};

fs::path temp_file(const std::string& name) {
    const fs::path dir = fs::temp_directory_path() / "eyesim_protocol_tests";
    fs::create_directories(dir);
    return dir / name;
}

std::vector<Rec> random_records(std::mt19937_64& rng, int n) {
    std::vector<Rec> r;
    std::uint64_t t = 1000;
    for (int i = 0; i < n; ++i) {
        t += uniform<std::uint64_t>(rng, 1, 30000);
        r.push_back({t, frame_of(random_message(rng), static_cast<std::uint16_t>(i))});
    }
    return r;
}

void write_all(const fs::path& path, const std::vector<Rec>& recs) {
    CaptureWriter w;
    REQUIRE(w.create(path.c_str()));
    for (const auto& r : recs) REQUIRE(w.write(r.t, r.bytes));
}

Bytes read_file(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return Bytes(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void write_file(const fs::path& p, const Bytes& b) {
    std::ofstream out(p, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
}

std::vector<Rec> read_all(const fs::path& path, CaptureStatus& last, CaptureReader& reader) {
    std::vector<Rec> out;
    REQUIRE(reader.open(path.c_str()));
    CaptureRecord rec;
    while ((last = reader.next(rec)) == CaptureStatus::Ok) out.push_back({rec.host_rx_us, Bytes(rec.bytes.begin(), rec.bytes.end())});
    return out;
}

}  // namespace

TEST_CASE("capture records read back exactly", "[protocol][capture]") {
    std::mt19937_64 rng(21);
    const auto recs = random_records(rng, 200);
    const fs::path path = temp_file("roundtrip.cap");
    write_all(path, recs);
    CaptureReader reader;
    CaptureStatus last{};
    CHECK(read_all(path, last, reader) == recs);
    CHECK(reader.kind() == CaptureKind::Capture);
    CHECK(last == CaptureStatus::End);
    CHECK(reader.dropped_bytes() == 0);
    // Header bytes as documented.
    std::ifstream f(path, std::ios::binary);
    char h[16];
    f.read(h, 16);
    CHECK(std::string(h, 8) == "EYESIMCP");
    CHECK(h[8] == 2);  // format_version 2
    CHECK(h[10] == 16);
}

TEST_CASE("a record torn at any byte is reported and all earlier records survive", "[protocol][capture]") {
    std::mt19937_64 rng(22);
    const auto recs = random_records(rng, 5);
    const fs::path path = temp_file("torn.cap");
    write_all(path, recs);
    const auto full = fs::file_size(path);
    const auto last_size = kCaptureRecordHeaderBytes + recs.back().bytes.size() + kCaptureRecordCrcBytes;
    for (std::uintmax_t cut = 1; cut < last_size; ++cut) {
        write_all(path, recs);
        fs::resize_file(path, full - cut);
        CaptureReader reader;
        CaptureStatus last{};
        const auto got = read_all(path, last, reader);
        REQUIRE(got == std::vector<Rec>(recs.begin(), recs.end() - 1));
        REQUIRE(last == CaptureStatus::Torn);
        CHECK(reader.dropped_bytes() == last_size - cut);
        CHECK(reader.bad_offset() == full - last_size);
    }
}

// Reads every record, going on past damaged stretches; counts the Corrupt statuses.
std::vector<Rec> read_through(const fs::path& path, CaptureStatus& last, CaptureReader& reader, int& corrupt) {
    std::vector<Rec> out;
    corrupt = 0;
    REQUIRE(reader.open(path.c_str()));
    CaptureRecord rec;
    while ((last = reader.next(rec)) == CaptureStatus::Ok || last == CaptureStatus::Corrupt) {
        if (last == CaptureStatus::Corrupt) ++corrupt;
        else out.push_back({rec.host_rx_us, Bytes(rec.bytes.begin(), rec.bytes.end())});
    }
    return out;
}

void flip_byte(const fs::path& path, std::uintmax_t off, std::uint8_t mask) {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(off));
    char c;
    f.get(c);
    f.seekp(static_cast<std::streamoff>(off));
    f.put(static_cast<char>(static_cast<std::uint8_t>(c) ^ mask));
}

std::uintmax_t record_size(const Rec& r) { return kCaptureRecordHeaderBytes + r.bytes.size() + kCaptureRecordCrcBytes; }

std::uintmax_t record_offset(const std::vector<Rec>& recs, std::size_t i) {
    std::uintmax_t off = kCaptureHeaderBytes;
    for (std::size_t k = 0; k < i; ++k) off += record_size(recs[k]);
    return off;
}

TEST_CASE("a last record damaged by a crash is torn; a damaged middle record is skipped and reading goes on",
          "[protocol][capture]") {
    std::mt19937_64 rng(23);
    const auto recs = random_records(rng, 6);
    const fs::path path = temp_file("damaged.cap");
    write_all(path, recs);
    const auto full = fs::file_size(path);
    flip_byte(path, full - 3, 0x40);  // inside the last record's CRC: the crash wrote a wrong tail
    CaptureReader reader;
    CaptureStatus last{};
    int corrupt = 0;
    CHECK(read_through(path, last, reader, corrupt) == std::vector<Rec>(recs.begin(), recs.end() - 1));
    CHECK(last == CaptureStatus::Torn);
    CHECK(corrupt == 0);
    CHECK(reader.bad_offset() == full - record_size(recs.back()));
    CHECK(reader.dropped_bytes() == record_size(recs.back()));

    std::vector<Rec> without_2 = recs;
    without_2.erase(without_2.begin() + 2);
    const std::uintmax_t off = record_offset(recs, 2);
    struct Damage {
        const char* what;
        std::uintmax_t at;
        std::uint8_t mask;
    };
    const Damage damages[] = {
        {"a payload byte", off + kCaptureRecordHeaderBytes + 3, 0x40},
        {"the time stamp", off + 6, 0x01},
        {"the CRC", off + record_size(recs[2]) - 1, 0x80},
        {"the length, out of range", off + 1, 0xC0},       // > kMaxCaptureRecordBytes
        {"the length, past the file end", off + 1, 0x20},  // + 8192 bytes: more than the file holds
        {"the length, one byte short", off, 0x01},          // the lowest bit: off by one either way
        {"the reserved field", off + 2, 0x04},
    };
    for (const Damage& d : damages) {
        SECTION(d.what) {
            write_all(path, recs);
            flip_byte(path, d.at, d.mask);
            CaptureReader r2;
            CHECK(read_through(path, last, r2, corrupt) == without_2);
            CHECK(last == CaptureStatus::End);
            CHECK(corrupt == 1);
            CHECK(r2.bad_offset() == off);
            CHECK(r2.last_skipped_bytes() == record_size(recs[2]));
            CHECK(r2.corrupt_regions() == 1);
            CHECK(r2.corrupt_bytes() == record_size(recs[2]));
            CHECK(r2.dropped_bytes() == 0);
        }
    }
    SECTION("garbage between two records") {
        write_all(path, recs);
        std::ifstream in(path, std::ios::binary);
        Bytes file((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        in.close();
        Bytes garbage(1000);
        for (auto& g : garbage) g = static_cast<std::uint8_t>(rng());
        const auto at = static_cast<std::ptrdiff_t>(record_offset(recs, 4));
        file.insert(file.begin() + at, garbage.begin(), garbage.end());
        std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(file.data()),
                                                     static_cast<std::streamsize>(file.size()));
        CaptureReader r3;
        CHECK(read_through(path, last, r3, corrupt) == recs);
        CHECK(last == CaptureStatus::End);
        CHECK(r3.corrupt_regions() == 1);
        CHECK(r3.corrupt_bytes() == garbage.size());
    }
    SECTION("long garbage: the next record lies across the resync window's edges") {
        for (std::size_t n = 4070; n < 4120; ++n) {  // the window screens 4096 header offsets at a time
            write_all(path, recs);
            std::ifstream in(path, std::ios::binary);
            Bytes file((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
            in.close();
            const auto at = static_cast<std::ptrdiff_t>(record_offset(recs, 1));
            file.insert(file.begin() + at, n, std::uint8_t{0});  // zeros: length 0 at every offset, never plausible
            std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(file.data()),
                                                         static_cast<std::streamsize>(file.size()));
            CaptureReader r4;
            INFO("garbage bytes " << n);
            REQUIRE(read_through(path, last, r4, corrupt) == recs);
            CHECK(r4.corrupt_bytes() == n);
        }
    }
}

TEST_CASE("random damage never loses an intact record nor delivers a damaged one", "[protocol][capture]") {
    std::mt19937_64 rng(29);
    const auto recs = random_records(rng, 120);
    const fs::path path = temp_file("random_damage.cap");
    std::vector<std::uintmax_t> starts;
    for (std::size_t i = 0; i < recs.size(); ++i) starts.push_back(record_offset(recs, i));
    for (int trial = 0; trial < 40; ++trial) {
        write_all(path, recs);
        const auto full = fs::file_size(path);
        std::vector<bool> damaged(recs.size(), false);
        const int flips = uniform<int>(rng, 1, 12);
        for (int k = 0; k < flips; ++k) {
            const auto at = uniform<std::uintmax_t>(rng, kCaptureHeaderBytes, full - 1);
            flip_byte(path, at, static_cast<std::uint8_t>(uniform<int>(rng, 1, 255)));
            const auto i = static_cast<std::size_t>(std::upper_bound(starts.begin(), starts.end(), at) - starts.begin()) - 1;
            damaged[i] = true;
        }
        std::vector<Rec> intact;
        for (std::size_t i = 0; i < recs.size(); ++i)
            if (!damaged[i]) intact.push_back(recs[i]);
        CaptureReader reader;
        CaptureStatus last{};
        int corrupt = 0;
        REQUIRE(read_through(path, last, reader, corrupt) == intact);
        // A damaged last record is a torn tail; every other damaged run is one skipped stretch.
        int runs = 0;
        for (std::size_t i = 0; i < recs.size(); ++i) runs += damaged[i] && (i == 0 || !damaged[i - 1]);
        const bool tail = damaged.back();
        CHECK(last == (tail ? CaptureStatus::Torn : CaptureStatus::End));
        CHECK(corrupt == runs - (tail ? 1 : 0));
    }
}

TEST_CASE("appending after a crash drops the torn tail and keeps everything else", "[protocol][capture]") {
    std::mt19937_64 rng(24);
    const auto first = random_records(rng, 10);
    const auto second = random_records(rng, 7);
    const fs::path path = temp_file("append.cap");
    write_all(path, first);
    fs::resize_file(path, fs::file_size(path) - 5);  // crash inside record 10
    CaptureWriter w;
    REQUIRE(w.append(path.c_str()));
    CHECK(w.recovered_records() == 9);
    CHECK(w.dropped_bytes() == kCaptureRecordHeaderBytes + first.back().bytes.size() + kCaptureRecordCrcBytes - 5);
    for (const auto& r : second) REQUIRE(w.write(r.t, r.bytes));
    w.close();
    std::vector<Rec> expect(first.begin(), first.end() - 1);
    expect.insert(expect.end(), second.begin(), second.end());
    CaptureReader reader;
    CaptureStatus last{};
    CHECK(read_all(path, last, reader) == expect);
    CHECK(last == CaptureStatus::End);

    // Appending to a missing file creates it; to a file with a torn header recreates it.
    const fs::path fresh = temp_file("fresh.cap");
    fs::remove(fresh);
    REQUIRE(w.append(fresh.c_str()));
    REQUIRE(w.write(5, second[0].bytes));
    w.close();
    CHECK(read_all(fresh, last, reader) == std::vector<Rec>{{5, second[0].bytes}});
    fs::resize_file(fresh, 5);
    REQUIRE(w.append(fresh.c_str()));
    w.close();
    CHECK(fs::file_size(fresh) == kCaptureHeaderBytes);
}

TEST_CASE("appending keeps the good records after a damaged stretch", "[protocol][capture]") {
    std::mt19937_64 rng(31);
    const auto first = random_records(rng, 10);
    const auto second = random_records(rng, 4);
    const fs::path path = temp_file("append_damaged.cap");
    write_all(path, first);
    flip_byte(path, record_offset(first, 4) + kCaptureRecordHeaderBytes + 1, 0x10);
    CaptureWriter w;
    REQUIRE(w.append(path.c_str()));
    CHECK(w.recovered_records() == 9);
    CHECK(w.dropped_bytes() == 0);
    for (const auto& r : second) REQUIRE(w.write(r.t, r.bytes));
    w.close();
    std::vector<Rec> expect = first;
    expect.erase(expect.begin() + 4);
    expect.insert(expect.end(), second.begin(), second.end());
    CaptureReader reader;
    CaptureStatus last{};
    int corrupt = 0;
    CHECK(read_through(path, last, reader, corrupt) == expect);
    CHECK(last == CaptureStatus::End);
    CHECK(corrupt == 1);

    // Replay goes on past the damaged record too: every other frame comes out, with its time.
    auto replay = std::make_unique<CaptureReplay>();
    REQUIRE(replay->open(path.c_str()));
    DecodedFrame f;
    std::uint64_t rx = 0;
    std::size_t k = 0;
    while (replay->next(f, rx)) {
        REQUIRE(k < expect.size());
        CHECK(frame_of(f.message, f.header.sequence) == expect[k].bytes);
        CHECK(rx == expect[k].t);
        ++k;
    }
    CHECK(k == expect.size());
    CHECK(replay->status() == CaptureStatus::End);
    CHECK(replay->reader().corrupt_regions() == 1);
    CHECK(replay->stats().errors() == 0);
}

TEST_CASE("appending refuses a file that is not a capture", "[protocol][capture]") {
    const fs::path path = temp_file("not_a_capture.bin");
    {
        std::ofstream f(path, std::ios::binary);
        f << "this is some other file, not a capture";
    }
    const auto before = fs::file_size(path);
    CaptureWriter w;
    CHECK_FALSE(w.append(path.c_str()));
    CHECK(fs::file_size(path) == before);
}

TEST_CASE("files without the magic are read as raw byte streams", "[protocol][capture]") {
    std::mt19937_64 rng(25);
    Bytes raw;
    while (raw.size() < 40000) {
        const Bytes f = frame_of(random_message(rng), 0);
        raw.insert(raw.end(), f.begin(), f.end());
    }
    const fs::path path = temp_file("raw.bin");
    {
        std::ofstream f(path, std::ios::binary);
        f.write(reinterpret_cast<const char*>(raw.data()), static_cast<std::streamsize>(raw.size()));
    }
    CaptureReader reader;
    CaptureStatus last{};
    const auto chunks = read_all(path, last, reader);
    CHECK(reader.kind() == CaptureKind::RawStream);
    CHECK(last == CaptureStatus::End);
    Bytes joined;
    for (const auto& c : chunks) {
        CHECK(c.t == 0);
        joined.insert(joined.end(), c.bytes.begin(), c.bytes.end());
    }
    CHECK(joined == raw);
    // An empty file is an empty raw stream.
    const fs::path empty = temp_file("empty.bin");
    { std::ofstream f(empty, std::ios::binary); }
    CHECK(read_all(empty, last, reader).empty());
    CHECK(last == CaptureStatus::End);
}

TEST_CASE("the writer rejects empty and oversize records", "[protocol][capture]") {
    const fs::path path = temp_file("limits.cap");
    CaptureWriter w;
    REQUIRE(w.create(path.c_str()));
    CHECK_FALSE(w.write(1, {}));
    const Bytes big(kMaxCaptureRecordBytes + 1, 0xAB);
    CHECK_FALSE(w.write(1, big));
    CHECK(w.write(1, std::span(big).first(kMaxCaptureRecordBytes)));
    w.close();
    CaptureReader reader;
    CaptureStatus last{};
    const auto got = read_all(path, last, reader);
    REQUIRE(got.size() == 1);
    CHECK(got[0].bytes.size() == kMaxCaptureRecordBytes);
    CHECK(last == CaptureStatus::End);
}

TEST_CASE("CaptureReplay yields every frame with its receive time, also from a torn capture", "[protocol][capture]") {
    std::mt19937_64 rng(26);
    auto recs = random_records(rng, 50);
    // One record carries two frames, and one frame is split over two records: records are received chunks.
    Bytes joined = recs[10].bytes;
    joined.insert(joined.end(), recs[11].bytes.begin(), recs[11].bytes.end());
    const Bytes head(recs[20].bytes.begin(), recs[20].bytes.begin() + 5);
    const Bytes tail(recs[20].bytes.begin() + 5, recs[20].bytes.end());
    std::vector<Rec> written;
    for (std::size_t i = 0; i < recs.size(); ++i) {
        if (i == 10) written.push_back({recs[10].t, joined});
        else if (i == 11) continue;
        else if (i == 20) {
            written.push_back({recs[20].t - 1, head});
            written.push_back({recs[20].t, tail});
        } else written.push_back(recs[i]);
    }
    const fs::path path = temp_file("replay.cap");
    write_all(path, written);
    fs::resize_file(path, fs::file_size(path) - 2);  // the last record is torn

    auto replay = std::make_unique<CaptureReplay>();
    REQUIRE(replay->open(path.c_str()));
    DecodedFrame f;
    std::uint64_t rx = 0;
    std::size_t k = 0;
    while (replay->next(f, rx)) {
        REQUIRE(k < recs.size() - 1);
        const Bytes again = frame_of(f.message, f.header.sequence);
        CHECK(again == recs[k].bytes);
        CHECK(rx == (k == 11 ? recs[10].t : recs[k].t));  // a frame gets the time of the record completing it
        ++k;
    }
    CHECK(k == recs.size() - 1);
    CHECK(replay->status() == CaptureStatus::Torn);
    CHECK(replay->kind() == CaptureKind::Capture);
    CHECK(replay->stats().errors() == 0);
    CHECK(replay->records() == written.size() - 1);
}

TEST_CASE("a capture that cannot be opened says why, naming the unsupported version", "[protocol][capture]") {
    // A good capture with its header then patched byte by byte (offsets of docs/protocol.md section 6).
    std::mt19937_64 rng(27);
    const fs::path good = temp_file("open_good.cap");
    write_all(good, random_records(rng, 3));
    const Bytes file = read_file(good);
    REQUIRE(file.size() > kCaptureHeaderBytes);
    CaptureReader reader;
    REQUIRE(reader.open(good.c_str()));
    CHECK(reader.open_error() == CaptureOpenError::None);
    CHECK(std::string(reader.open_error_message()).empty());
    CHECK(reader.found_format_version() == kCaptureVersion);
    CHECK(reader.file_bytes() == file.size());

    Bytes v7 = file;
    v7[8] = 7, v7[9] = 0;  // format_version 7
    const fs::path p7 = temp_file("open_v7.cap");
    write_file(p7, v7);
    CHECK_FALSE(reader.open(p7.c_str()));
    CHECK(reader.open_error() == CaptureOpenError::UnsupportedVersion);
    CHECK(reader.found_format_version() == 7);
    CHECK(std::string(reader.open_error_message()) == "capture format version 7 not supported (this build reads 1 to 2)");
    // The replay reports the same reason through its reader.
    auto replay = std::make_unique<CaptureReplay>();
    CHECK_FALSE(replay->open(p7.c_str()));
    CHECK(replay->reader().open_error() == CaptureOpenError::UnsupportedVersion);
    CHECK(std::string(replay->reader().open_error_message()) ==
          "capture format version 7 not supported (this build reads 1 to 2)");

    Bytes v258 = file;
    v258[8] = 2, v258[9] = 1;  // little-endian 0x0102 = 258
    write_file(p7, v258);
    CHECK_FALSE(reader.open(p7.c_str()));
    CHECK(std::string(reader.open_error_message()) == "capture format version 258 not supported (this build reads 1 to 2)");

    Bytes h20 = file;
    h20[10] = 20;  // header_bytes 20
    const fs::path p20 = temp_file("open_h20.cap");
    write_file(p20, h20);
    CHECK_FALSE(reader.open(p20.c_str()));
    CHECK(reader.open_error() == CaptureOpenError::BadHeaderSize);
    CHECK(reader.found_header_bytes() == 20);
    CHECK(std::string(reader.open_error_message()) == "capture header size 20 not supported (this build reads 16)");

    const fs::path short_header = temp_file("open_short.cap");
    write_file(short_header, Bytes(file.begin(), file.begin() + 10));
    CHECK_FALSE(reader.open(short_header.c_str()));
    CHECK(reader.open_error() == CaptureOpenError::ShortHeader);
    CHECK(std::string(reader.open_error_message()) == "capture file header truncated (10 of 16 bytes)");

    const fs::path missing = temp_file("open_missing.cap");
    fs::remove(missing);
    CHECK_FALSE(reader.open(missing.c_str()));
    CHECK(reader.open_error() == CaptureOpenError::CannotOpen);
    CHECK(std::string(reader.open_error_message()).rfind("cannot open for reading: ", 0) == 0);
    CHECK_FALSE(reader.open(temp_file("").parent_path().c_str()));  // a directory
    CHECK(reader.open_error() == CaptureOpenError::CannotOpen);

    // A successful open after a failed one clears the reason.
    REQUIRE(reader.open(good.c_str()));
    CHECK(reader.open_error() == CaptureOpenError::None);
    CHECK(std::string(reader.open_error_message()).empty());
    CHECK(std::string(to_string(CaptureOpenError::UnsupportedVersion)) == "unsupported_version");
}

TEST_CASE("capture version 2: the host's own commands are Sent records, a separate stream in replay",
          "[protocol][capture]") {
    std::mt19937_64 rng(28);
    const auto received = random_records(rng, 40);
    // The host's commands, one frame each, between the received records; their own sequence numbers.
    std::vector<Rec> sent;
    for (int i = 0; i < 10; ++i) {
        Command c;
        c.command_id = static_cast<std::uint32_t>(100 + i);
        c.opcode = static_cast<std::uint8_t>(Opcode::RegisterRead);
        c.address = 0x1000u + 4u * static_cast<std::uint32_t>(i);
        sent.push_back({received[4 * i].t + 1, frame_of(Message{c}, static_cast<std::uint16_t>(i))});
    }
    const fs::path path = temp_file("directions.cap");
    {
        CaptureWriter w;
        REQUIRE(w.create(path.c_str()));
        CHECK(w.format_version() == kCaptureVersion);
        for (std::size_t i = 0; i < received.size(); ++i) {
            REQUIRE(w.write(received[i].t, received[i].bytes));
            if (i % 4 == 0) REQUIRE(w.write(sent[i / 4].t, sent[i / 4].bytes, CaptureDirection::Sent));
        }
    }
    // The reader gives each record its direction, in file order.
    CaptureReader reader;
    REQUIRE(reader.open(path.c_str()));
    CHECK(reader.found_format_version() == 2);
    CaptureRecord rec;
    std::size_t n_sent = 0, n_received = 0;
    while (reader.next(rec) == CaptureStatus::Ok) {
        if (rec.direction == CaptureDirection::Sent) {
            REQUIRE(n_sent < sent.size());
            CHECK(Bytes(rec.bytes.begin(), rec.bytes.end()) == sent[n_sent++].bytes);
        } else {
            REQUIRE(n_received < received.size());
            CHECK(Bytes(rec.bytes.begin(), rec.bytes.end()) == received[n_received++].bytes);
        }
    }
    CHECK(n_sent == sent.size());
    CHECK(n_received == received.size());

    // Replay: the two-argument next() gives the received stream alone, with no sequence gap from the commands.
    auto replay = std::make_unique<CaptureReplay>();
    REQUIRE(replay->open(path.c_str()));
    DecodedFrame f;
    std::uint64_t t = 0;
    std::size_t k = 0;
    while (replay->next(f, t)) {
        REQUIRE(k < received.size());
        CHECK(frame_of(f.message, f.header.sequence) == received[k].bytes);
        CHECK(t == received[k].t);
        ++k;
    }
    CHECK(k == received.size());
    CHECK(replay->stats().errors() == 0);
    CHECK(replay->sent_records() == sent.size());
    CHECK(replay->records() == received.size() + sent.size());
    // The three-argument next() gives both, each command after the received record it followed.
    REQUIRE(replay->open(path.c_str()));
    bool from_host = false;
    std::vector<bool> order;
    std::size_t commands = 0;
    while (replay->next(f, t, from_host)) {
        order.push_back(from_host);
        if (from_host) {
            REQUIRE(commands < sent.size());
            CHECK(frame_of(f.message, f.header.sequence) == sent[commands].bytes);
            CHECK(t == sent[commands].t);
            ++commands;
        }
    }
    CHECK(commands == sent.size());
    REQUIRE(order.size() == received.size() + sent.size());
    CHECK(order[0] == false);
    CHECK(order[1] == true);
    CHECK(replay->sent_stats().errors() == 0);
    CHECK(replay->sent_stats().sequence_gaps == 0);

    // A direction above 1 is damage (the record is skipped, those after it are kept); so is any direction but 0
    // in a version-1 file, which has no directions.
    const Bytes file = read_file(path);
    const std::size_t second = kCaptureHeaderBytes + kCaptureRecordHeaderBytes + received[0].bytes.size() +
                               kCaptureRecordCrcBytes;  // the first Sent record
    REQUIRE(file[second + 2] == 1);
    Bytes bad = file;
    bad[second + 2] = 2;
    const fs::path p_bad = temp_file("directions_bad.cap");
    write_file(p_bad, bad);
    REQUIRE(reader.open(p_bad.c_str()));
    std::size_t good = 0;
    CaptureStatus s;
    while ((s = reader.next(rec)) == CaptureStatus::Ok || s == CaptureStatus::Corrupt) good += s == CaptureStatus::Ok;
    CHECK(good == received.size() + sent.size() - 1);
    CHECK(reader.corrupt_regions() == 1);
    Bytes v1 = file;
    v1[8] = 1;  // format_version 1: the Sent records are now damage, the received ones all survive
    write_file(p_bad, v1);
    REQUIRE(reader.open(p_bad.c_str()));
    good = 0;
    while ((s = reader.next(rec)) == CaptureStatus::Ok || s == CaptureStatus::Corrupt) {
        good += s == CaptureStatus::Ok;
        if (s == CaptureStatus::Ok) CHECK(rec.direction == CaptureDirection::Received);
    }
    CHECK(good == received.size());
    // Appending to a version-1 file keeps its format: received records go in, Sent ones are refused.
    Bytes v1_clean(file.begin(), file.begin() + static_cast<std::ptrdiff_t>(second));
    v1_clean[8] = 1;
    write_file(p_bad, v1_clean);
    CaptureWriter w;
    REQUIRE(w.append(p_bad.c_str()));
    CHECK(w.format_version() == 1);
    CHECK(w.write(5, received[1].bytes));
    CHECK_FALSE(w.write(6, sent[0].bytes, CaptureDirection::Sent));
    w.close();
    REQUIRE(reader.open(p_bad.c_str()));
    good = 0;
    while (reader.next(rec) == CaptureStatus::Ok) ++good;
    CHECK(good == 2);
}
