// Writes the fuzz seed corpus from the test vectors of docs/protocol.md: for each vector one raw-mode seed
// (mode byte 0 + the stream bytes) and one framed-mode seed (mode byte 1 + a control/length/payload record per
// frame in the vector). Usage: eyesim_fuzz_seed docs/protocol.md CORPUS_DIR
#include <cstdio>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

int main(int argc, char** argv) {
    if (argc != 3) {
        std::fprintf(stderr, "usage: %s docs/protocol.md CORPUS_DIR\n", argv[0]);
        return 2;
    }
    std::ifstream doc(argv[1]);
    if (!doc) {
        std::fprintf(stderr, "%s: cannot open\n", argv[1]);
        return 1;
    }
    std::filesystem::create_directories(argv[2]);
    std::string line, name;
    std::vector<std::uint8_t> bytes;
    bool inside = false;
    int written = 0;
    auto write = [&](const std::string& file, const std::vector<std::uint8_t>& b) {
        std::ofstream out(std::filesystem::path(argv[2]) / file, std::ios::binary);
        out.write(reinterpret_cast<const char*>(b.data()), static_cast<std::streamsize>(b.size()));
        ++written;
    };
    while (std::getline(doc, line)) {
        if (!inside && line.rfind("```eyesim-vector name=", 0) == 0) {
            name = line.substr(22);
            bytes.clear();
            inside = true;
        } else if (inside && line == "```") {
            inside = false;
            std::vector<std::uint8_t> raw{0};
            raw.insert(raw.end(), bytes.begin(), bytes.end());
            write("seed-raw-" + name, raw);
            // Framed seed: walk the frames of the vector by their headers.
            std::vector<std::uint8_t> framed{1};
            for (std::size_t i = 0; i + 8 <= bytes.size();) {
                const std::size_t len = bytes[i + 6] | (bytes[i + 7] << 8);
                if (bytes[i] != 0xE7 || bytes[i + 1] != 0x5A || len > 511 || i + 12 + len > bytes.size()) {
                    ++i;
                    continue;
                }
                framed.push_back(static_cast<std::uint8_t>((bytes[i + 3] & 0x07) | (len >= 256 ? 0x20 : 0)));
                framed.push_back(static_cast<std::uint8_t>(len & 0xFF));
                framed.insert(framed.end(), bytes.begin() + static_cast<std::ptrdiff_t>(i + 8),
                              bytes.begin() + static_cast<std::ptrdiff_t>(i + 8 + len));
                i += 12 + len;
            }
            if (framed.size() > 1) write("seed-framed-" + name, framed);
        } else if (inside) {
            std::istringstream hex(line);
            std::string byte;
            while (hex >> byte) bytes.push_back(static_cast<std::uint8_t>(std::stoul(byte, nullptr, 16)));
        }
    }
    std::printf("%d seed files written to %s\n", written, argv[2]);
    return written > 0 ? 0 : 1;
}
