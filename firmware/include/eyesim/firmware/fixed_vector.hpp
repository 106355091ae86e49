#pragma once
/// \file
/// Fixed-capacity vector: storage inside the object, no heap, no exceptions. Pushing past the capacity fails
/// (returns false) instead of growing, so the caller decides what to drop.

#include <array>
#include <cstddef>
#include <type_traits>

namespace eyesim::firmware {

/// A vector of at most `Capacity` trivially copyable elements stored inline.
template <typename T, std::size_t Capacity>
class FixedVector {
    static_assert(std::is_trivially_copyable_v<T>, "FixedVector holds plain data only");

public:
    /// Largest number of elements this vector can hold.
    static constexpr std::size_t capacity() noexcept { return Capacity; }
    /// Number of elements held.
    std::size_t size() const noexcept { return size_; }
    /// True when no element is held.
    bool empty() const noexcept { return size_ == 0; }
    /// True when another push would fail.
    bool full() const noexcept { return size_ == Capacity; }
    /// Appends `v`; returns false (and changes nothing) when full.
    bool push_back(const T& v) noexcept {
        if (size_ == Capacity) return false;
        items_[size_++] = v;
        return true;
    }
    /// Removes every element.
    void clear() noexcept { size_ = 0; }
    /// Element `i`; `i` must be below size().
    T& operator[](std::size_t i) noexcept { return items_[i]; }
    /// Element `i`; `i` must be below size().
    const T& operator[](std::size_t i) const noexcept { return items_[i]; }
    /// First element (range-for support).
    T* begin() noexcept { return items_.data(); }
    /// One past the last element.
    T* end() noexcept { return items_.data() + size_; }
    /// First element (range-for support).
    const T* begin() const noexcept { return items_.data(); }
    /// One past the last element.
    const T* end() const noexcept { return items_.data() + size_; }
    /// Contiguous storage.
    T* data() noexcept { return items_.data(); }
    /// Contiguous storage.
    const T* data() const noexcept { return items_.data(); }

private:
    std::array<T, Capacity> items_{};
    std::size_t size_ = 0;
};

}  // namespace eyesim::firmware
