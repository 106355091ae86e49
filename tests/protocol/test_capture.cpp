#include "eyesim/protocol/capture.hpp"
#include "eyesim/protocol/capture_replay.hpp"
#include "test_util.hpp"

#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <memory>

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
    CHECK(h[8] == 1);
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

TEST_CASE("a last record damaged by a crash is torn, a damaged middle record is corrupt", "[protocol][capture]") {
    std::mt19937_64 rng(23);
    const auto recs = random_records(rng, 6);
    const fs::path path = temp_file("damaged.cap");
    write_all(path, recs);
    const auto full = fs::file_size(path);
    auto flip_at = [&](std::uintmax_t off) {
        std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
        f.seekg(static_cast<std::streamoff>(off));
        char c;
        f.get(c);
        f.seekp(static_cast<std::streamoff>(off));
        f.put(static_cast<char>(c ^ 0x40));
    };
    flip_at(full - 3);  // inside the last record's CRC: the crash wrote a wrong tail
    CaptureReader reader;
    CaptureStatus last{};
    CHECK(read_all(path, last, reader) == std::vector<Rec>(recs.begin(), recs.end() - 1));
    CHECK(last == CaptureStatus::Torn);

    write_all(path, recs);
    // Third record's payload byte: records 0 and 1 survive, reading stops as corrupt.
    std::uintmax_t off = kCaptureHeaderBytes;
    for (int i = 0; i < 2; ++i) off += kCaptureRecordHeaderBytes + recs[i].bytes.size() + kCaptureRecordCrcBytes;
    flip_at(off + kCaptureRecordHeaderBytes + 3);
    CaptureReader r2;
    CHECK(read_all(path, last, r2) == std::vector<Rec>(recs.begin(), recs.begin() + 2));
    CHECK(last == CaptureStatus::Corrupt);
    CHECK(r2.bad_offset() == off);
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
