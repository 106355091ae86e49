// The main job end to end, as a user runs it: `eyesim demo` with two real processes over TCP loopback.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

namespace {
std::string run(const std::string& cmd, int& rc) {
    std::string out;
    FILE* p = ::popen(cmd.c_str(), "r");
    if (!p) return out;
    std::array<char, 4096> buf{};
    size_t n;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) out.append(buf.data(), n);
    rc = ::pclose(p);
    return out;
}
}  // namespace

TEST_CASE("eyesim demo: the surgeon peels the membrane through eyesim-device over TCP → tracking → simulation", "[host][e2e]") {
    // The README's main job, at its defaults: the forceps can only close through the device's PedalState, so a
    // grasp here proves the pedal crossed the wire. The simulation steps once per reference field (400 frames)
    // however many low-latency parts the field came in.
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_demo").string();
    std::filesystem::remove_all(dir);
    int rc = -1;
    const std::string out =
        run(std::string(EYESIM_EXE) + " demo --json --out " + dir + " --device " + EYESIM_DEVICE_EXE + " 2>/dev/null", rc);
    REQUIRE(rc == 0);
    const auto j = nlohmann::json::parse(out);
    CHECK(j["scene"] == "membrane-peel");
    CHECK(j["frames"].get<int>() >= 350);  // 400 fields per camera at 50 fields/s: one simulation step each
    CHECK(j["frames"].get<int>() <= 400);
    CHECK(j["errors"].get<int>() == 0);
    // A clean loopback link at PAL pace: nothing lost, and the device ended it (after the recording).
    for (const char* k : {"sequence_gaps", "frames_lost", "fields_lost", "queue_overflows", "resyncs", "time_jumps"})
        CHECK(j["loss"][k].get<int>() == 0);
    CHECK(j["link_end"] == "device closed the link");
    const auto& sc = j["scores"];
    CHECK(sc["grabs"].get<int>() >= 1);
    CHECK(sc["peeled_area_mm2"].get<double>() > 0.0);
    CHECK(sc["peeled_percent"].get<double>() > 5.0);
    CHECK(sc["springs_torn"].get<int>() > 0);
    CHECK(sc["lift_off_warnings"].get<int>() == 0);
    CHECK(j["passed"].get<bool>());
    int grabs = 0;
    for (const auto& e : j["events"]) grabs += e["kind"] == "grab";
    CHECK(grabs == sc["grabs"].get<int>());
    CHECK(j["marker3d_rms_um"].get<double>() < 250.0);
    CHECK(j["tip_rms_um"].get<double>() < 400.0);
    // Field end → poses ready on the host clock, through the ping/pong offset. eyesim-device's clock is modelled:
    // paced to wall time with up to 200 µs of slack when idle, and lagging it by milliseconds when the machine is
    // busy (other tests run beside this one), so the figure is only as good as that pacing. With low-latency parts
    // it covers only the few frames given at a field's end (a closing part that brought something new; 4 of 3,908
    // on seed 1): its sign is the clock offset's error (seen: -1.8 ms in CI). What must hold is a figure of the
    // right size.
    REQUIRE(j["latency_us"].is_object());  // a device at PAL pace: its clock can be placed on the host's
    const double lat_p50 = j["latency_us"]["p50"].get<double>();
    CHECK(j["latency_us"]["frames"].get<int>() > 0);
    CHECK(std::abs(lat_p50) < 25000.0);
    CHECK(j["transfer_us"]["p50"].get<double>() <= lat_p50);
    CHECK(std::abs(j["device_clock_rate"].get<double>() - 1.0) < 0.02);
    // No bound on the tail: on a 2-core machine running other tests beside this one, the device process is
    // sometimes starved for a fifth of a second, and its modelled clock stamps those fields late (seen: p99 192 ms).
    CHECK(j["latency_us"]["p99"].get<double>() >= lat_p50);
    // The default chain is the low-latency one: the device sends each blob as the FPGA completes it and the
    // filters take it at once; each field's frame is reported 19 ms after its exposure (before the field is read
    // out: exposure mid → last line is 21.8 ms), its poses smoothed by the other cameras' parts taken since.
    // Measured 19.3-19.7 ms p50 (seeds 41-44); interpolating whole fields gives 35.4 ms. The lower bound allows the
    // clock offset's error, the upper one the live loop's wake-up on a loaded machine (the modelled chain's 19.0 ms
    // is asserted in test_validate_sync).
    const double e50 = j["exposure_to_pose_us"]["p50"].get<double>();
    CHECK(e50 > 15000.0);
    CHECK(e50 < 22500.0);
    CHECK(j["exposure_to_pose_us"]["frames"].get<int>() == j["frames"].get<int>());  // a pose per field
    CHECK(j["stages"]["tracking"]["p50_us"].get<double>() > 0.0);
    CHECK(j["stages"]["tissue"]["p50_us"].get<double>() > 0.0);
    CHECK(std::filesystem::exists(dir + "/report/index.html"));
    CHECK(std::filesystem::exists(dir + "/recording/truth.jsonl"));
    // The stereo animation of the whole run: 10 frames per second of the 8 s procedure.
    if (j.contains("animation")) {
        CHECK(j["animation"]["frames"].get<int>() >= 75);
        CHECK(std::filesystem::file_size(dir + "/report/animation.mp4") > 10000);
    } else {
        bool said = false;  // only a machine without EGL or an FFmpeg encoder has none, and says why
        for (const auto& w : j["warnings"]) said = said || w.get<std::string>().rfind("no animation", 0) == 0;
        CHECK(said);
    }
    std::filesystem::remove_all(dir);
}

TEST_CASE("eyesim sim on recorded device streams: peel-hard warns, vitrectomy removes, injection detaches and warns",
          "[host][e2e]") {
    // Recordings of each synthetic surgeon through the FPGA model and the wire protocol (never the truth poses).
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_surgeons").string();
    std::filesystem::remove_all(dir);
    const std::string exe = EYESIM_EXE, scenes = std::string(EYESIM_SOURCE_DIR) + "/scenes/";
    int rc = -1;
    auto sim = [&](const char* scenario, const char* scene, double seconds) {
        const std::string rec = dir + "/" + scenario;
        run(exe + " synth --scenario " + scenario + " --seconds " + std::to_string(seconds) + " --seed 17 --out " + rec +
                " --json",
            rc);
        REQUIRE(rc == 0);
        const std::string out = run(exe + " sim --scene " + scenes + scene + ".json --recording " + rec + " --json", rc);
        REQUIRE(rc == 0);
        return nlohmann::json::parse(out);
    };
    const auto hard = sim("peel-hard", "membrane-peel", 8.0);
    CHECK(hard["scores"]["grabs"].get<int>() >= 1);
    CHECK(hard["scores"]["lift_off_warnings"].get<int>() > 0);
    CHECK_FALSE(hard["passed"].get<bool>());

    const auto vit = sim("vitrectomy", "vitrectomy", 6.4);
    CHECK(vit["scores"]["removed_area_mm2"].get<double>() > 0.5);

    const auto inj = sim("injection", "retina-relocation", 4.0);
    CHECK(inj["scores"]["nodes_detached"].get<int>() > 0);
    CHECK(inj["scores"]["tear_warnings"].get<int>() > 0);
    for (const auto& e : inj["events"])  // one warning: the flick at 3 s, not tracking noise
        if (e["kind"] == "tear_warning") CHECK((e["t_s"].get<double>() > 2.9 && e["t_s"].get<double>() < 3.4));

    std::filesystem::remove_all(dir);
}

TEST_CASE("eyesim sim: a bad scene file or a missing device is one line and a non-zero exit", "[host][e2e]") {
    int rc = -1;
    std::string err = run(std::string(EYESIM_EXE) + " sim --scene /nonexistent.json --scenario surgery 2>&1", rc);
    CHECK(rc != 0);
    CHECK(err == "eyesim: error: /nonexistent.json: cannot open scene file\n");
    err = run(std::string(EYESIM_EXE) + " sim --scene " + EYESIM_SOURCE_DIR +
                  "/scenes/membrane-peel.json --connect tcp://127.0.0.1:1 2>&1",
              rc);
    CHECK(rc != 0);
    CHECK(err.rfind("eyesim: error: tcp://127.0.0.1:1", 0) == 0);
    CHECK(std::count(err.begin(), err.end(), '\n') == 1);
}

TEST_CASE("the tool chain a hardware engineer uses: synth → fpga → capture → protocol decode → sim", "[host][e2e]") {
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_cli").string();
    std::filesystem::remove_all(dir);
    const std::string exe = EYESIM_EXE;
    int rc = -1;
    auto synth = nlohmann::json::parse(
        run(exe + " synth --scenario surgery --seconds 0.3 --seed 4 --out " + dir + "/rec --json", rc));
    REQUIRE(rc == 0);
    CHECK(synth["fields"].get<int>() == 15);

    auto fpga = nlohmann::json::parse(run(exe + " fpga --recording " + dir + "/rec --out " + dir + "/cap.bin --json", rc));
    REQUIRE(rc == 0);
    CHECK(fpga["errors"].get<int>() == 0);
    CHECK(fpga["truth"].get<bool>());
    CHECK(fpga["centroid_rms_px"].get<double>() < 0.1);

    // The refinement stage replaces centroids, not blobs; its accuracy is tested on unoccluded markers in
    // tests/fpga-model/test_sphere_fit.cpp (this summary also counts partly occluded ones, docs/fpga-pipeline.md).
    auto refined = nlohmann::json::parse(run(exe + " fpga --recording " + dir + "/rec --refine --json", rc));
    REQUIRE(rc == 0);
    CHECK(refined["blobs"] == fpga["blobs"]);
    for (size_t c = 0; c < 3; ++c) CHECK(refined["cameras"][c]["matched"] == fpga["cameras"][c]["matched"]);
    CHECK(refined["refined"].get<int>() * 3 > fpga["blobs"].get<int>());
    CHECK(refined["centroid_rms_px"].get<double>() < 0.1);

    // The same centroid error split by the truth's visibility adds up to the whole; the fit is far closer to the
    // rendered centroid on clear markers (a partly hidden one keeps the pipeline's centroid more often).
    for (const auto* run_j : {&fpga, &refined}) {
        const nlohmann::json& vis = (*run_j)["centroid_by_visibility"];
        const int64_t n_clear = vis["clear"]["matched"].get<int64_t>(), n_hidden = vis["partly_hidden"]["matched"].get<int64_t>();
        int64_t matched = 0;
        for (size_t c = 0; c < 3; ++c) matched += (*run_j)["cameras"][c]["matched"].get<int64_t>();
        CHECK(n_clear + n_hidden == matched);
        REQUIRE(n_clear > 20);
        REQUIRE(n_hidden > 0);
        const double r_clear = vis["clear"]["rms_px"].get<double>(), r_hidden = vis["partly_hidden"]["rms_px"].get<double>();
        const double whole = std::sqrt((n_clear * r_clear * r_clear + n_hidden * r_hidden * r_hidden) / matched);
        CHECK(std::abs(whole - (*run_j)["centroid_rms_px"].get<double>()) < 1e-9);
        // So do the mean x errors, weighted by the counts.
        const double bias_x = (n_clear * vis["clear"]["bias_px"]["x"].get<double>() +
                               n_hidden * vis["partly_hidden"]["bias_px"]["x"].get<double>()) / matched;
        CHECK(std::abs(bias_x - (*run_j)["centroid_bias_px"]["x"].get<double>()) < 1e-9);
    }
    CHECK(refined["centroid_by_visibility"]["clear"]["rms_px"].get<double>() <
          0.6 * fpga["centroid_by_visibility"]["clear"]["rms_px"].get<double>());

    // validate --refine: the same chain with refined centroids, scored against the rendered truth of the markers
    // no other object hides (its own matching), is closer to it than without.
    auto plain_v = nlohmann::json::parse(run(exe + " validate --recording " + dir + "/rec --json", rc));
    REQUIRE(rc == 0);
    auto refined_v = nlohmann::json::parse(run(exe + " validate --recording " + dir + "/rec --refine --json", rc));
    REQUIRE(rc == 0);
    CHECK(refined_v["refined"].get<int>() > 0);
    CHECK(refined_v["refused"].contains("chi2"));
    CHECK_FALSE(plain_v.contains("refined"));
    CHECK(refined_v["centroid_rms_px"].get<double>() < 0.75 * plain_v["centroid_rms_px"].get<double>());

    // Every FieldMarkers message of the capture decodes; its markers add up to the FPGA model's blobs.
    const std::string lines = run(exe + " protocol decode " + dir + "/cap.bin --json 2>/dev/null", rc);
    REQUIRE(rc == 0);
    size_t markers = 0, messages = 0, pedals = 0, pos = 0;
    uint64_t last_rx_us = 0;
    while (pos < lines.size()) {
        const size_t end = lines.find('\n', pos);
        const auto j = nlohmann::json::parse(lines.substr(pos, end - pos));
        // Receive times of a model-written capture (docs/protocol.md section 6): the device clock, at or after the
        // device time the frame carries, by the modelled transmission latency (well under 1 ms), never decreasing.
        const uint64_t rx_us = j.at("host_rx_us").get<uint64_t>();
        const uint64_t device_us =
            j["type"] == "FieldMarkers" ? j.at("field_end_us").get<uint64_t>() : j.at("device_us").get<uint64_t>();
        INFO(j.dump());
        CHECK(rx_us > device_us);
        CHECK(rx_us <= device_us + 1000);
        CHECK(rx_us >= last_rx_us);
        last_rx_us = rx_us;
        if (j["type"] == "FieldMarkers") {
            ++messages;
            markers += j["markers"].size();
        }
        pedals += j["type"] == "PedalState";
        pos = end == std::string::npos ? lines.size() : end + 1;
    }
    CHECK(messages >= 45);  // 15 fields × 3 cameras, more when a field needs several parts
    CHECK(pedals == 15);    // the truth's pedal, once per field period, as the device sends it
    CHECK(markers == fpga["blobs"].get<size_t>());

    // The capture replays into the simulator.
    auto sim = nlohmann::json::parse(run(exe + " sim --scene " + EYESIM_SOURCE_DIR + "/scenes/membrane-peel.json --capture " +
                                             dir + "/cap.bin --rig " + dir + "/rec/rig.yaml --json",
                                         rc));
    REQUIRE(rc == 0);
    CHECK(sim["frames"].get<int>() >= 12);
    CHECK(sim["errors"].get<int>() == 0);

    // A capture cut mid-record: everything before the tear is still used, with a warning, not an error.
    std::filesystem::resize_file(dir + "/cap.bin", std::filesystem::file_size(dir + "/cap.bin") - 7);
    auto torn = nlohmann::json::parse(run(exe + " sim --scene " + EYESIM_SOURCE_DIR + "/scenes/membrane-peel.json --capture " +
                                              dir + "/cap.bin --rig " + dir + "/rec/rig.yaml --json",
                                          rc));
    REQUIRE(rc == 0);
    CHECK(torn["frames"].get<int>() >= sim["frames"].get<int>() - 1);
    REQUIRE(torn["warnings"].size() == 1);
    CHECK(torn["warnings"][0].get<std::string>().find("torn tail") != std::string::npos);

    // A damaged byte in the middle costs that record only: replay goes on after it, with a warning.
    {
        std::fstream f(dir + "/cap.bin", std::ios::in | std::ios::out | std::ios::binary);
        const auto at = static_cast<std::streamoff>(std::filesystem::file_size(dir + "/cap.bin") / 2);
        f.seekg(at);
        const int c = f.get();
        f.seekp(at);
        f.put(static_cast<char>(c ^ 0x5a));
    }
    auto damaged = nlohmann::json::parse(run(exe + " sim --scene " + EYESIM_SOURCE_DIR +
                                                 "/scenes/membrane-peel.json --capture " + dir + "/cap.bin --rig " +
                                                 dir + "/rec/rig.yaml --json",
                                             rc));
    REQUIRE(rc == 0);
    CHECK(damaged["frames"].get<int>() >= sim["frames"].get<int>() - 2);
    // One line per finding, each naming its byte offset; the frames the damage cost are counted (sequence gaps).
    int stretches = 0, tails = 0;
    for (const auto& w : damaged["warnings"]) {
        stretches += w.get<std::string>().find("damaged stretch at byte ") != std::string::npos;
        tails += w.get<std::string>().find("torn tail at byte ") != std::string::npos;
    }
    CHECK(stretches == 1);
    CHECK(tails == 1);
    CHECK(damaged["loss"]["frames_lost"].get<int>() >= 1);
    CHECK(damaged["loss"]["sequence_gaps"].get<int>() >= 1);
    std::filesystem::remove_all(dir);
}

TEST_CASE("usage errors, garbage captures and empty truth are one line and a non-zero exit", "[host][e2e]") {
    const std::string exe = EYESIM_EXE;
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_usage").string();
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    int rc = -1;
    auto one_line_error = [&](const std::string& args, int want_rc, const std::string& starts) {
        const std::string err = run(exe + " " + args + " 2>&1 >/dev/null", rc);
        INFO(args << " -> " << err);
        CHECK(WEXITSTATUS(rc) == want_rc);
        CHECK(err.rfind("eyesim: error: " + starts, 0) == 0);
        CHECK(std::count(err.begin(), err.end(), '\n') == 1);
    };
    one_line_error("bogus", 2, "'bogus': unknown command");
    one_line_error("synth --scenario nope --out " + dir + "/x", 2, "--scenario: nope not in");
    run(exe + " synth --scenario static --seconds 0.06 --out " + dir + "/rec 2>&1", rc);
    REQUIRE(rc == 0);
    one_line_error("fpga --recording " + dir + "/rec --fields 0", 2, "--fields: Value 0 not in range");
    one_line_error("validate --recording " + dir + "/rec --truth-noise-px nan", 2,
                   "--truth-noise-px: Value nan not a finite number");  // CLI::Range alone lets NaN through
    one_line_error("validate --recording " + dir + "/rec --max-fields -3", 2, "--max-fields: Value -3 not a finite");
    one_line_error("sim --scene " + std::string(EYESIM_SOURCE_DIR) + "/scenes/membrane-peel.json --recording " + dir +
                       "/rec --seconds -1",
                   2, "--seconds: Value -1 not a finite number");
    // demo checks its scene before it synthesises anything or starts the device (whose exit line would follow).
    {
        std::ofstream(dir + "/bad_scene.json") << "{\"duration_s\": ";
    }
    one_line_error("demo --out " + dir + "/demo --scene " + dir + "/bad_scene.json", 1, dir + "/bad_scene.json: not valid JSON");
    CHECK_FALSE(std::filesystem::exists(dir + "/demo/recording"));
    // A file of random bytes is a raw stream without a single frame: an error, not an empty result.
    {
        std::ofstream f(dir + "/garbage.bin", std::ios::binary);
        unsigned x = 12345;
        for (int i = 0; i < 5000; ++i) f.put(static_cast<char>((x = x * 1103515245u + 12345u) >> 24));
    }
    one_line_error("track --capture " + dir + "/garbage.bin --rig " + dir + "/rec/rig.yaml", 1,
                   dir + "/garbage.bin: no protocol frames received");
    // A capture of a format version this build does not read: the reason, naming the version, for every command
    // that opens captures.
    {
        std::ofstream f(dir + "/v7.cap", std::ios::binary);
        f.write("EYESIMCP\x07\x00\x10\x00\x00\x00\x00\x00", 16);
    }
    const std::string v7 = dir + "/v7.cap: capture format version 7 not supported (this build reads 1 to 2)";
    one_line_error("protocol decode " + dir + "/v7.cap", 1, v7);
    one_line_error("track --capture " + dir + "/v7.cap --rig " + dir + "/rec/rig.yaml", 1, v7);
    one_line_error("sim --scene " + std::string(EYESIM_SOURCE_DIR) + "/scenes/membrane-peel.json --capture " + dir +
                       "/v7.cap --rig " + dir + "/rec/rig.yaml",
                   1, v7);
    // An empty file holds nothing to decode.
    std::ofstream(dir + "/empty.bin").close();
    one_line_error("protocol decode " + dir + "/empty.bin", 1, dir + "/empty.bin: no bytes");
    // A truth file that is present but empty is not silently ignored.
    std::ofstream(dir + "/rec/truth.jsonl", std::ios::trunc).close();
    one_line_error("fpga --recording " + dir + "/rec --json", 1, dir + "/rec/truth.jsonl: no lines");
    std::filesystem::remove_all(dir);
}

namespace {
// A device that accepts one host, sends `bytes`, then keeps the link open and silent until the host hangs up.
class StalledDevice {
public:
    explicit StalledDevice(std::vector<char> bytes) : bytes_(std::move(bytes)) {
        fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        a.sin_port = 0;
        REQUIRE(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
        REQUIRE(::listen(fd_, 1) == 0);
        socklen_t n = sizeof a;
        ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &n);
        port_ = ntohs(a.sin_port);
        thread_ = std::thread([this] {
            const int c = ::accept(fd_, nullptr, nullptr);
            if (c < 0) return;
            for (size_t off = 0; off < bytes_.size();) {
                const ssize_t w = ::send(c, bytes_.data() + off, bytes_.size() - off, MSG_NOSIGNAL);
                if (w <= 0) break;
                off += size_t(w);
            }
            char sink[4096];
            while (::recv(c, sink, sizeof sink, 0) > 0) {  // swallow the host's commands, answer none
            }
            ::close(c);
        });
    }
    ~StalledDevice() {
        ::shutdown(fd_, SHUT_RDWR);
        ::close(fd_);
        if (thread_.joinable()) thread_.join();
    }
    std::string uri() const { return "tcp://127.0.0.1:" + std::to_string(port_); }

private:
    std::vector<char> bytes_;
    int fd_ = -1;
    int port_ = 0;
    std::thread thread_;
};

// The received bytes of each record of a capture file (docs/protocol.md, section 6): one frame each.
std::vector<std::vector<char>> capture_records(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::vector<char> file((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::vector<std::vector<char>> out;
    for (size_t p = 16; p + 12 <= file.size();) {
        const size_t len = size_t(uint8_t(file[p])) | size_t(uint8_t(file[p + 1])) << 8;
        out.emplace_back(file.begin() + std::ptrdiff_t(p + 12), file.begin() + std::ptrdiff_t(p + 12 + len));
        p += 12 + len + 4;
    }
    return out;
}

std::vector<char> capture_stream(const std::string& path) {
    std::vector<char> out;
    for (const auto& r : capture_records(path)) out.insert(out.end(), r.begin(), r.end());
    return out;
}
}  // namespace

TEST_CASE("a device that stops sending ends a live run with a warning, not a hang", "[host][e2e]") {
    const std::string exe = EYESIM_EXE;
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_stall").string();
    std::filesystem::remove_all(dir);
    int rc = -1;
    run(exe + " synth --scenario surgery --seconds 0.3 --out " + dir + "/rec 2>&1", rc);
    REQUIRE(rc == 0);
    run(exe + " fpga --recording " + dir + "/rec --out " + dir + "/cap.bin 2>&1", rc);
    REQUIRE(rc == 0);
    const std::vector<char> stream = capture_stream(dir + "/cap.bin");
    REQUIRE(stream.size() > 1000);

    {  // frames, then silence: the frames are used, the run ends after --stall-s with a warning
        StalledDevice dev(stream);
        const auto t0 = std::chrono::steady_clock::now();
        const std::string out = run(exe + " track --connect " + dev.uri() + " --rig " + dir +
                                        "/rec/rig.yaml --stall-s 1 --json 2>" + dir + "/err.txt",
                                    rc);
        const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        REQUIRE(WEXITSTATUS(rc) == 0);
        const auto j = nlohmann::json::parse(out);
        CHECK(j["frames"].get<int>() >= 10);
        CHECK(j["end"].get<std::string>().find("device stalled") != std::string::npos);
        CHECK_FALSE(j["clean_end"].get<bool>());
        CHECK(wall_s < 10.0);
        std::ifstream err(dir + "/err.txt");
        const std::string e((std::istreambuf_iterator<char>(err)), std::istreambuf_iterator<char>());
        CHECK(e.find("eyesim: warning: " + dev.uri() + ": no bytes for 1.0 s: device stalled") != std::string::npos);
    }
    {  // a lossy link: every 7th frame never arrives; the summary counts exactly those, and warns
        const auto records = capture_records(dir + "/cap.bin");
        std::vector<char> lossy;
        int dropped = 0;
        for (size_t i = 0; i < records.size(); ++i) {
            if (i > 5 && i + 5 < records.size() && i % 7 == 0) {
                ++dropped;
                continue;
            }
            lossy.insert(lossy.end(), records[i].begin(), records[i].end());
        }
        StalledDevice dev(lossy);
        const std::string out = run(exe + " track --connect " + dev.uri() + " --rig " + dir +
                                        "/rec/rig.yaml --stall-s 1 --json 2>" + dir + "/err.txt",
                                    rc);
        REQUIRE(WEXITSTATUS(rc) == 0);
        const auto j = nlohmann::json::parse(out);
        CHECK(j["loss"]["frames_lost"].get<int>() == dropped);
        CHECK(j["loss"]["sequence_gaps"].get<int>() == dropped);
        CHECK(j["frames"].get<int>() >= 10);
        std::ifstream err(dir + "/err.txt");
        const std::string e((std::istreambuf_iterator<char>(err)), std::istreambuf_iterator<char>());
        CHECK(e.find("eyesim: warning: " + dev.uri() + ": " + std::to_string(dropped) + " frames lost") != std::string::npos);
    }
    {  // silence from the start: an error naming the stall
        StalledDevice dev({});
        const std::string err = run(exe + " track --connect " + dev.uri() + " --rig " + dir +
                                        "/rec/rig.yaml --stall-s 0.5 2>&1 >/dev/null",
                                    rc);
        CHECK(WEXITSTATUS(rc) == 1);
        CHECK(err.find("eyesim: error: " + dev.uri() + ": no protocol frames received (0 bytes skipped; no bytes for 0.5 s: device stalled)") !=
              std::string::npos);
    }
    {  // the simulator's live path: the scene runs on what arrived, the report carries the warning
        StalledDevice dev(stream);
        const std::string out = run(exe + " sim --scene " + std::string(EYESIM_SOURCE_DIR) +
                                        "/scenes/membrane-peel.json --connect " + dev.uri() + " --rig " + dir +
                                        "/rec/rig.yaml --stall-s 1 --json 2>/dev/null",
                                    rc);
        REQUIRE(WEXITSTATUS(rc) == 0);
        const auto j = nlohmann::json::parse(out);
        CHECK(j["frames"].get<int>() >= 10);
        CHECK(j["link_end"].get<std::string>().find("device stalled") != std::string::npos);
        bool warned = false;
        for (const auto& w : j["warnings"]) warned = warned || w.get<std::string>().find("device stalled") != std::string::npos;
        CHECK(warned);
    }
    std::filesystem::remove_all(dir);
}

TEST_CASE("fpga --refine on DV video: partly hidden markers fitted with their shaft or the eye left out, placed by "
          "the chain's own poses",
          "[host][e2e]") {
    // A lossy video's chroma moves the pipeline's centroid of a marker its shaft or the eye partly hides by 0.1 px
    // and more; the occlusion-aware fit (occluders from a tracker run on the refined blobs) takes the luma's outline
    // instead. Seed 6: nothing was tuned on it.
    const std::string dir = (std::filesystem::temp_directory_path() / "eyesim_test_shaft_dv").string();
    std::filesystem::remove_all(dir);
    const std::string exe = EYESIM_EXE;
    int rc = -1;
    run(exe + " synth --scenario sweep --seconds 0.6 --seed 6 --format dv --out " + dir + " --json", rc);
    REQUIRE(rc == 0);
    const auto with = nlohmann::json::parse(run(exe + " fpga --recording " + dir + " --refine --json", rc));
    REQUIRE(rc == 0);
    const auto without = nlohmann::json::parse(run(exe + " fpga --recording " + dir + " --refine --no-hints --json", rc));
    REQUIRE(rc == 0);
    CHECK(without["hinted_fits"].get<int>() == 0);
    CHECK(with["hinted_fits"].get<int>() > 300);  // the instruments' markers and the eye's near its outline
    CHECK(with["refused"]["hint_outline"].get<int>() == 0);  // lossy: fitted beside the eye's outline too
    CHECK(with["blobs"] == without["blobs"]);
    const double hidden_with = with["centroid_by_visibility"]["partly_hidden"]["rms_px"].get<double>();
    const double hidden_without = without["centroid_by_visibility"]["partly_hidden"]["rms_px"].get<double>();
    INFO("partly hidden markers: " << hidden_with << " px with the hints, " << hidden_without << " px without");
    CHECK(hidden_with < 0.8 * hidden_without);
    CHECK(with["centroid_rms_px"].get<double>() < without["centroid_rms_px"].get<double>());
    // The parity bias of the 4:2:0 chroma on partly hidden markers shrinks with it.
    const auto& bias = with["centroid_by_visibility"]["partly_hidden"]["bias_px"];
    const auto& bias0 = without["centroid_by_visibility"]["partly_hidden"]["bias_px"];
    CHECK(std::abs(bias["y_top"].get<double>() - bias["y_bottom"].get<double>()) <
          std::abs(bias0["y_top"].get<double>() - bias0["y_bottom"].get<double>()));

    // validate --refine has the same hints, from its own tracker.
    const auto v = nlohmann::json::parse(run(exe + " validate --recording " + dir + " --refine --json", rc));
    REQUIRE(rc == 0);
    CHECK(v["hinted_fits"].get<int>() > 300);
    std::filesystem::remove_all(dir);
}
