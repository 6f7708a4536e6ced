// The epilogue the conv kernels share, pasted where they say CONV_EPILOGUE
// by runtime/infer/src/gpu/codegen.rs: bias, ReLU, residual add, clamp (in
// that order, as each kernel's RELU, RESIDUAL, CLAMP say) and the store of
// one output value, element `at` of the output, of channel `oc`.
fn epilogue(at: u32, oc: u32, sum: f32) {
    var v = sum + f32(weights[p.b_offset + oc]);
    if (RELU) {
        v = max(v, 0.0);
    }
    if (RESIDUAL) {
        v += f32(residual[p.res_offset + at]);
    }
    if (CLAMP) {
        v = clamp(v, 0.0, 1.0);
    }
    dst[p.out_offset + at] = {{DST_T}}(v);
}
