// A pixel's label from the label words of its camera samples' first hits, shared by the
// annotation pass (annotate.comp, thin lens) and the path tracer's labels from its own
// samples (path_trace.comp, `PathPush::labels`), so both resolve words identically.
// Needs interface.glsl (LABEL_MAX_SAMPLES, LABEL_CLASS_SHIFT).
#ifndef LABELS_GLSL
#define LABELS_GLSL

// True when the label word is a defect's (class != 0).
bool label_is_defect(uint word) {
    return ((word >> LABEL_CLASS_SHIFT) & 0xffu) != 0u;
}

// The word most of words[0 .. count) are (ties: the earliest sample's), count >= 1.
uint label_majority(uint words[LABEL_MAX_SAMPLES], uint count) {
    uint best = words[0], best_n = 0u;
    for (uint a = 0u; a < count; ++a) {
        uint k = 0u;
        for (uint b = 0u; b < count; ++b) k += words[b] == words[a] ? 1u : 0u;
        if (k > best_n) {
            best_n = k;
            best = words[a];
        }
    }
    return best;
}

// Share of words[0 .. count) that are a defect's, count >= 1.
float label_coverage(uint words[LABEL_MAX_SAMPLES], uint count) {
    uint defect = 0u;
    for (uint s = 0u; s < count; ++s) defect += label_is_defect(words[s]) ? 1u : 0u;
    return float(defect) / float(count);
}
#endif
