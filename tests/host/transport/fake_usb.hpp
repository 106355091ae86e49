#pragma once
// A fake USB bus with one eyesim device, emulating bulk endpoint semantics: the device's IN data is split into
// wMaxPacketSize packets; a host IN request completes on a short packet, a zero-length packet or a full buffer.
// OUT transfers are reassembled the same way, so a missing zero-length packet shows up as two commands merged.
#include "eyesim/transport/usb.hpp"

#include <algorithm>
#include <chrono>
#include <thread>
#include <deque>
#include <memory>
#include <mutex>
#include <vector>

namespace eyesim::test {

struct FakeBus {
    std::mutex m;
    bool plugged = true;
    std::uint64_t generation = 0;  // +1 per plug-in; an open device of an older generation is gone
    std::uint16_t mps = transport::kUsbMaxPacketHighSpeed;
    std::deque<std::vector<std::uint8_t>> in_packets;     // device → host, USB packets (size ≤ mps; 0 = ZLP)
    std::vector<std::vector<std::uint8_t>> out_transfers;  // host → device, reassembled transfers
    std::vector<std::uint8_t> out_partial;
    std::vector<std::size_t> in_request_sizes;            // sizes the host asked for
    int opens = 0;
    bool arrival_pending = false;

    /// The device sends one transfer: split into packets, a ZLP when it filled the last packet exactly.
    void device_send(const std::vector<std::uint8_t>& transfer) {
        std::scoped_lock lock(m);
        std::size_t off = 0;
        do {
            const std::size_t n = std::min<std::size_t>(mps, transfer.size() - off);
            in_packets.emplace_back(transfer.begin() + static_cast<std::ptrdiff_t>(off),
                                    transfer.begin() + static_cast<std::ptrdiff_t>(off + n));
            off += n;
            if (n == mps && off == transfer.size()) in_packets.emplace_back();  // ZLP
        } while (off < transfer.size());
    }
    void unplug() {
        std::scoped_lock lock(m);
        plugged = false;
        in_packets.clear();
    }
    void replug() {
        std::scoped_lock lock(m);
        plugged = true;
        ++generation;
        arrival_pending = true;
    }
};

class FakeDevice final : public transport::BulkDevice {
public:
    FakeDevice(std::shared_ptr<FakeBus> bus, std::uint64_t gen) : bus_(std::move(bus)), gen_(gen) {}
    transport::UsbStatus bulk_in(std::uint8_t* buf, std::size_t len, std::size_t& got, unsigned) override {
        std::scoped_lock lock(bus_->m);
        got = 0;
        if (!alive()) return transport::UsbStatus::no_device;
        bus_->in_request_sizes.push_back(len);
        if (len % bus_->mps != 0) return transport::UsbStatus::io;  // the host must ask in whole packets
        while (!bus_->in_packets.empty()) {
            auto p = std::move(bus_->in_packets.front());
            bus_->in_packets.pop_front();
            std::copy(p.begin(), p.end(), buf + got);
            got += p.size();
            if (p.size() < bus_->mps || got == len) return transport::UsbStatus::ok;  // short packet ends it
        }
        return transport::UsbStatus::timeout;  // (partial data is returned with the timeout, like libusb)
    }
    transport::UsbStatus bulk_out(const std::uint8_t* buf, std::size_t len, std::size_t& sent, unsigned) override {
        std::scoped_lock lock(bus_->m);
        sent = 0;
        if (!alive()) return transport::UsbStatus::no_device;
        std::size_t off = 0;
        do {  // the host controller splits the transfer into packets; a short one ends the device's transfer
            const std::size_t n = std::min<std::size_t>(bus_->mps, len - off);
            bus_->out_partial.insert(bus_->out_partial.end(), buf + off, buf + off + n);
            off += n;
            if (n < bus_->mps) {
                bus_->out_transfers.push_back(std::move(bus_->out_partial));
                bus_->out_partial.clear();
            }
        } while (off < len);
        sent = len;
        return transport::UsbStatus::ok;
    }
    std::uint16_t max_packet_in() const override { return bus_->mps; }
    std::uint16_t max_packet_out() const override { return bus_->mps; }

private:
    bool alive() const { return bus_->plugged && bus_->generation == gen_; }
    std::shared_ptr<FakeBus> bus_;
    std::uint64_t gen_;
};

class FakeBackend final : public transport::UsbBackend {
public:
    explicit FakeBackend(std::shared_ptr<FakeBus> bus, bool hotplug = true) : bus_(std::move(bus)), hotplug_(hotplug) {}
    transport::UsbStatus open(const transport::UsbIds& ids, std::unique_ptr<transport::BulkDevice>& out,
                              std::string& why) override {
        std::scoped_lock lock(bus_->m);
        ++bus_->opens;
        if (!bus_->plugged || ids.vendor_id != transport::kUsbVendorId || ids.product_id != transport::kUsbProductId) {
            why = "fake: no device found";
            return transport::UsbStatus::not_found;
        }
        out = std::make_unique<FakeDevice>(bus_, bus_->generation);
        return transport::UsbStatus::ok;
    }
    bool hotplug_supported() const override { return hotplug_; }
    bool wait_for_arrival(int timeout_ms) override {
        {
            std::scoped_lock lock(bus_->m);
            if (hotplug_ && bus_->arrival_pending) {
                bus_->arrival_pending = false;
                return true;
            }
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(std::min(timeout_ms, 2)));
        return false;
    }

private:
    std::shared_ptr<FakeBus> bus_;
    bool hotplug_;
};

}  // namespace eyesim::test
