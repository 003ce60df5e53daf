// The standoff charts' rows (a compensation's, one trace of a board's): the nominal program's
// standoff over the rebuilt surface, the compensated one's, and its posterior band.
// The standoff rows of a trace (µm) from its rebuilt deviation samples [[s, dz]] (mm), with the
// posterior band of the compensated standoff (± the reconstruction's bound) when it has one.
export function standoffRows(samples, standoffMm, boundMm) {
  return samples.map(([s, dz]) => ({ s_mm: s, nominal_program_um: (standoffMm - dz) * 1000, compensated_um: standoffMm * 1000,
    ...(boundMm != null ? { band_lo_um: (standoffMm - boundMm) * 1000, band_hi_um: (standoffMm + boundMm) * 1000 } : {}) }));
}
export const standoffBand = (boundMm) => (boundMm != null ? { lo: "band_lo_um", hi: "band_hi_um" } : null);
export const bandNote = (boundMm) => (boundMm != null ? `; shaded: the compensated standoff ± the reconstruction's bound `
  + `(${(boundMm * 1000).toFixed(2)} µm, posterior under the fitted field)` : "");
