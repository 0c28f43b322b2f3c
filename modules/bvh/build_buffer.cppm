// canopy.bvh:build_buffer — how the BVH's large arrays are allocated.
//
// large_array_allocator<T> (exported: the type of bvh::wide_nodes and bvh::blocks): std::allocator,
// except that arrays of 2 MiB and more start on a 2 MiB boundary and are offered to the kernel as
// huge pages (Linux's transparent huge pages in `madvise` mode, where the system allows them): one
// page fault per 2 MiB instead of one per 4 KiB when the builder first writes them. They come from
// and return to canopy.bvh:block_cache, which keeps freed ones for the next build (their first
// writes are what costs on virtual machines that hand freed memory back to the host). Elements
// are constructed as by std::allocator.
//
// build_buffer<T> (the builder's own): a vector whose resize() leaves new elements as the
// allocation made them. std::vector::resize value-initialises every new element on one thread:
// for the 1.3M-triangle sphere, 42 MB of references and 84 MB of binary nodes (2n − 1, of which a
// quarter is used) were zeroed before the parallel build started. With build_buffer, pages are
// first touched by the (parallel) code that fills them, and pages never used are never touched.
// Contract: T is trivially copyable and trivially destructible (an implicit-lifetime type, whose
// objects the allocation creates); every element is written whole before it is read. The
// builder's uses: prim_ref (filled in parallel from the input), bvh_node (each node written by
// the build step that creates it).
module;
#include <cstddef>
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>
export module canopy.bvh:build_buffer;
import :block_cache;

namespace canopy::detail {
// Set by unwritten_resize (below) on the thread that resizes.
inline thread_local bool resize_leaves_unwritten = false;
} // namespace canopy::detail

export namespace canopy {

template <typename T>
struct large_array_allocator {
    using value_type = T;
    static constexpr std::size_t huge_page = detail::huge_page_bytes;

    large_array_allocator() = default;
    template <typename U>
    large_array_allocator(large_array_allocator<U> const&) noexcept {}

    T* allocate(std::size_t n) {
        if (n > std::size_t(-1) / sizeof(T)) throw std::bad_array_new_length();
        std::size_t const bytes = n * sizeof(T);
        if (bytes < huge_page) return std::allocator<T>().allocate(n);
        if (bytes > std::size_t(-1) - huge_page) throw std::bad_array_new_length();
        // Whole huge pages (the last one too), from the cache of freed blocks where one fits.
        return static_cast<T*>(detail::block_cache::instance().allocate((bytes + huge_page - 1) / huge_page * huge_page));
    }
    void deallocate(T* p, std::size_t n) noexcept {
        if (n * sizeof(T) < huge_page) return std::allocator<T>().deallocate(p, n);
        detail::block_cache::instance().deallocate(p);
    }

    // Value-initialisation (resize(n)), as std::allocator does it, except inside a builder's
    // detail::unwritten_resize on this thread, where elements of implicit-lifetime types are left
    // as the allocation made them (the builder then writes each one whole, in parallel).
    template <typename U>
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        if constexpr (std::is_trivially_copyable_v<U> && std::is_trivially_destructible_v<U>)
            if (detail::resize_leaves_unwritten) return;
        ::new (static_cast<void*>(p)) U();
    }
    // (Construction with arguments: std::allocator_traits' default, std::construct_at.)

    template <typename U>
    bool operator==(large_array_allocator<U> const&) const noexcept {
        return true;
    }
};

} // namespace canopy

namespace canopy::detail {

template <typename T>
struct uninitialized_allocator : large_array_allocator<T> {
    static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                  "uninitialized_allocator: for implicit-lifetime element types only");
    template <typename U>
    struct rebind {
        using other = uninitialized_allocator<U>;
    };
    uninitialized_allocator() = default;
    template <typename U>
    uninitialized_allocator(uninitialized_allocator<U> const&) noexcept {}

    // Value-initialisation (resize(n)): nothing; the caller writes the element before reading it.
    template <typename U>
    void construct(U*) noexcept {}
    template <typename U, typename... Args>
    void construct(U* p, Args&&... args) {
        std::construct_at(p, std::forward<Args>(args)...);
    }
};

template <typename T>
using build_buffer = std::vector<T, uninitialized_allocator<T>>;

// v.resize(n) for a vector of the BVH's (large_array_allocator), with the new elements left as
// the allocation made them, not value-initialised on this one thread. Contract: T is an
// implicit-lifetime type and the caller writes every new element whole before it is read (or the
// vector is destroyed).
template <typename T>
void unwritten_resize(std::vector<T, large_array_allocator<T>>& v, std::size_t n) {
    static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                  "unwritten_resize: for implicit-lifetime element types only");
    struct flag {
        flag() { resize_leaves_unwritten = true; }
        ~flag() { resize_leaves_unwritten = false; }
    } const set;
    v.resize(n);
}

} // namespace canopy::detail
