// canopy.bvh:block_cache — large arrays freed by one build, kept for the next.
//
// Every large array of a build (the builder's references and binary nodes, the BVH's wide nodes
// and triangle blocks: 2 MiB and more, see large_array_allocator) is a fresh mapping from the
// kernel, and its pages are faulted in by the first write. Where memory freed to the kernel is
// handed back to a hypervisor (virtio-balloon free page reporting, as on Firecracker and other
// cloud VMs), that first write costs the host's fault as well: about 6 ms per MiB measured on the
// project's build machines, 40 times the kernel's zeroing, so a 2M-triangle build spent more time
// faulting its arrays than building its tree. Small blocks stay in the C library's heap and never
// pay it; arrays of tens of MiB are unmapped on free and do.
//
// The cache keeps freed large blocks (up to memory_cache_limit() bytes in all, 1 GiB by default)
// and hands them to the next allocations that fit, best fit, a block at most twice the size asked
// for. Contract: a block returned by allocate() holds whatever its last user wrote (the allocators
// above construct or write every element before it is read); a block is never shared; every
// operation is thread-safe. release_cached_memory() frees what the cache holds, and
// set_memory_cache_limit(0) turns the cache off.
module;
#include <cstddef>
#include <mutex>
#include <new>
#include <unordered_map>
#include <vector>
#if defined(__linux__)
#include <sys/mman.h>
#endif
export module canopy.bvh:block_cache;

export namespace canopy {

// The most bytes of freed large arrays kept for reuse (default 1 GiB; 0: none kept).
std::size_t memory_cache_limit() noexcept;
// Sets that limit, freeing the blocks beyond it.
void set_memory_cache_limit(std::size_t bytes) noexcept;
// Frees every block the cache holds; returns their bytes.
std::size_t release_cached_memory() noexcept;
// The bytes the cache holds now.
std::size_t cached_memory() noexcept;

} // namespace canopy

namespace canopy::detail {

// The size and alignment of the blocks (one huge page on x86-64 Linux); large_array_allocator's.
inline constexpr std::size_t huge_page_bytes = std::size_t(2) << 20;

class block_cache {
public:
    static block_cache& instance() {
        // Never destroyed: a BVH with static storage duration may free its arrays after any
        // other static object's destructor ran.
        static block_cache* const cache = new block_cache;
        return *cache;
    }

    // A block of at least `bytes` (a multiple of huge_page_bytes), 2 MiB-aligned and offered to
    // the kernel as huge pages; a cached one when one fits.
    void* allocate(std::size_t bytes) {
        {
            std::lock_guard lock(mutex_);
            auto best = free_.end();
            for (auto it = free_.begin(); it != free_.end(); ++it)
                if (it->bytes >= bytes && it->bytes / 2 <= bytes && (best == free_.end() || it->bytes < best->bytes))
                    best = it;
            if (best != free_.end()) {
                entry const found = *best;
                live_.emplace(found.pointer, found.bytes); // first: if it throws, the block stays cached
                free_.erase(best);
                cached_ -= found.bytes;
                return found.pointer;
            }
        }
        void* const p = ::operator new(bytes, std::align_val_t(huge_page_bytes));
#if defined(__linux__) && defined(MADV_HUGEPAGE)
        ::madvise(p, bytes, MADV_HUGEPAGE); // advice only: where it fails, pages stay 4 KiB
#endif
        try {
            std::lock_guard lock(mutex_);
            live_.emplace(p, bytes);
        } catch (...) { // no room to note it
            ::operator delete(p, std::align_val_t(huge_page_bytes));
            throw;
        }
        return p;
    }

    // Takes back a block from allocate(): kept while the cache has room, else freed.
    void deallocate(void* p) noexcept {
        std::size_t bytes = 0;
        {
            std::lock_guard lock(mutex_);
            auto const it = live_.find(p);
            if (it != live_.end()) {
                bytes = it->second;
                live_.erase(it);
            }
            if (bytes != 0 && bytes <= limit_) {
                try {
                    free_.push_back({p, bytes});
                    cached_ += bytes;
                    p = nullptr;
                    trim(limit_);
                } catch (...) { // no room to note it: freed instead
                }
            }
        }
        if (p) ::operator delete(p, std::align_val_t(huge_page_bytes));
    }

    std::size_t limit() noexcept {
        std::lock_guard lock(mutex_);
        return limit_;
    }
    void set_limit(std::size_t bytes) noexcept {
        std::lock_guard lock(mutex_);
        limit_ = bytes;
        trim(limit_);
    }
    std::size_t release() noexcept {
        std::lock_guard lock(mutex_);
        std::size_t const was = cached_;
        trim(0);
        return was;
    }
    std::size_t cached() noexcept {
        std::lock_guard lock(mutex_);
        return cached_;
    }

private:
    struct entry {
        void* pointer;
        std::size_t bytes;
    };

    // Frees the oldest cached blocks until at most `bytes` stay (under the lock).
    void trim(std::size_t bytes) noexcept {
        std::size_t drop = 0;
        while (cached_ > bytes && drop < free_.size()) {
            cached_ -= free_[drop].bytes;
            ::operator delete(free_[drop].pointer, std::align_val_t(huge_page_bytes));
            ++drop;
        }
        free_.erase(free_.begin(), free_.begin() + std::ptrdiff_t(drop));
    }

    std::mutex mutex_;
    std::vector<entry> free_;                        // oldest first
    std::unordered_map<void*, std::size_t> live_;    // blocks handed out, with their sizes
    std::size_t cached_ = 0;
    std::size_t limit_ = std::size_t(1) << 30;
};

} // namespace canopy::detail

namespace canopy {

std::size_t memory_cache_limit() noexcept { return detail::block_cache::instance().limit(); }
void set_memory_cache_limit(std::size_t bytes) noexcept { detail::block_cache::instance().set_limit(bytes); }
std::size_t release_cached_memory() noexcept { return detail::block_cache::instance().release(); }
std::size_t cached_memory() noexcept { return detail::block_cache::instance().cached(); }

} // namespace canopy
