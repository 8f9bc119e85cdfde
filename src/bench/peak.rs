//! Published FP32 (non-tensor) peaks of common adapters, for the "fraction of peak" column.

/// Vendor-published FP32 peak in GFLOP/s for adapters we know by name, else `None`.
pub fn peak_fp32_gflops(adapter_name: &str) -> Option<f64> {
    let n = adapter_name.to_lowercase();
    // (substring, GFLOP/s); first match wins, so more specific names come first.
    const TABLE: &[(&str, f64)] = &[
        ("h200", 67_000.0),
        ("h100 pcie", 51_200.0),
        ("h100", 66_900.0),
        ("a100", 19_500.0),
        ("l40s", 91_600.0),
        ("rtx 4090", 82_600.0),
        ("rtx 4080", 48_700.0),
        ("rtx 3090 ti", 40_000.0),
        ("rtx 3090", 35_600.0),
        ("rtx 3080", 29_800.0),
        ("rtx 5090", 104_800.0),
        ("rtx 2080 ti", 13_400.0),
    ];
    TABLE.iter().find(|(k, _)| n.contains(k)).map(|&(_, v)| v)
}

#[cfg(test)]
mod tests {
    #[test]
    fn known_and_unknown_adapters() {
        assert_eq!(super::peak_fp32_gflops("NVIDIA H100 80GB HBM3"), Some(66_900.0));
        assert_eq!(super::peak_fp32_gflops("NVIDIA H100 PCIe"), Some(51_200.0));
        assert_eq!(super::peak_fp32_gflops("llvmpipe (LLVM 15.0.6, 256 bits)"), None);
    }
}
