// The parameter block and bindings every layer kernel shares, pasted into
// each kernel where it says LAYER_BINDINGS, by
// runtime/infer/src/gpu/codegen.rs.
// The parameters sit in a read-only storage buffer, not a uniform one:
// lavapipe (Mesa 22.3) specialises a shader on the values of the uniforms
// its loops and branches read, and re-specialises it whenever they change,
// which they do at every layer. That cost 4–5 ms per conv dispatch on this
// machine, more than the convolution itself at 64² (docs/benchmarks.md).
// Mirrors `Params` in runtime/infer/src/gpu/params.rs (a test checks
// sizes and offsets). Sizes are of the layer's input; offsets are in
// elements of the bound buffer's type, so one buffer can hold several
// tensors (concatenation by layout).
struct Params {
    width: u32, // of the layer's input
    height: u32,
    cin: u32,
    cout: u32,
    in_offset: u32,
    out_offset: u32,
    res_offset: u32,
    w_offset: u32,
    b_offset: u32,
    // The fused level's first convolution (conv_fused.wgsl; 0 elsewhere):
    // its outputs, and its weights' and bias's offsets.
    mid: u32,
    first_w_offset: u32,
    first_b_offset: u32,
}

@group(0) @binding(0) var<storage, read> p: Params;
@group(0) @binding(1) var<storage, read> src: array<{{SRC_T}}>;
@group(0) @binding(2) var<storage, read> weights: array<{{W_T}}>;
@group(0) @binding(3) var<storage, read_write> dst: array<{{DST_T}}>;
@group(0) @binding(4) var<storage, read> residual: array<{{RES_T}}>;
