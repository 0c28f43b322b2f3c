// canopy.scene:error — the one exception type for bad scene input.
//
// Every loader, generator and compile step, the benchmark file readers
// (canopy.plugins.bench:formats) and image I/O (canopy.image) report bad input by throwing scene_error, and nothing else does.
// (Other errors are not bad input: a broken precondition of the library's API throws
// std::invalid_argument, canopy.distributed's remote_failure carries another process's error.)
// Its message names the file, the place in it (line, element or node, where known) and the
// problem, as
//   "forest.json: node 'trees': instance target 'oak' does not exist"
//   "bunny.obj:1207: vertex index 40112 is out of range (35947 vertices so far)"
// so a user can find the fault without a debugger. A file name over 160 bytes is shown shortened
// (its first 60 and last 99 bytes), so no message line grows with a hostile name. Nothing is
// half-loaded: registry::load rolls the scene back to where it was when a loader throws (see
// scene::make_mark and scene::roll_back).
module;
#include <cstddef>
#include <stdexcept>
#include <string>
#include <string_view>
export module canopy.scene:error;

export namespace canopy {

class scene_error : public std::runtime_error {
public:
    // file: the file at fault (may be empty for scenes built in code); where: "12" (a line),
    // "node 'x'", "material 3", ... (may be empty); problem: what is wrong, in plain words.
    scene_error(std::string file, std::string where, std::string const& problem)
        : std::runtime_error(compose(file, where, problem)), file_(std::move(file)), where_(std::move(where)),
          problem_(problem) {}

    std::string const& file() const noexcept { return file_; }
    std::string const& where() const noexcept { return where_; }
    std::string const& problem() const noexcept { return problem_; }

private:
    static std::string compose(std::string const& file, std::string const& where, std::string const& problem) {
        std::string m = file.empty() ? std::string("scene") : shown_file(file);
        if (!where.empty()) {
            bool const line = where.find_first_not_of("0123456789") == std::string::npos;
            m += line ? ":" + where : ": " + where;
        }
        return m + ": " + problem;
    }

    // A file name of more than 160 bytes (a path built from a hostile name) is shown by its first 60
    // and last 99 bytes around "…", cut at UTF-8 character boundaries; file() keeps it whole.
    static std::string shown_file(std::string const& file) {
        constexpr std::size_t longest = 160, head = 60, tail = 99;
        if (file.size() <= longest) return file;
        auto continuation = [&](std::size_t i) { return (static_cast<unsigned char>(file[i]) & 0xC0) == 0x80; };
        std::size_t h = head, t = file.size() - tail;
        while (h > 0 && continuation(h)) --h;
        while (t < file.size() && continuation(t)) ++t;
        return file.substr(0, h) + "…" + file.substr(t);
    }
    std::string file_, where_, problem_;
};

// A piece of input quoted in a message: at most `max` bytes of `text` (cut at a UTF-8 character
// boundary, then "…"), control bytes shown as '?'. A message never carries megabytes of input.
inline std::string excerpt(std::string_view text, std::size_t max = 40) {
    std::size_t n = text.size();
    if (n > max) {
        n = max;
        while (n > 0 && (static_cast<unsigned char>(text[n]) & 0xC0) == 0x80) --n; // not inside a character
    }
    std::string out(text.substr(0, n));
    for (char& c : out)
        if (static_cast<unsigned char>(c) < 0x20 || c == 0x7F) c = '?';
    if (n < text.size()) out += "…";
    return out;
}

} // namespace canopy
