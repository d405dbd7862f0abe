/* slope_estimator.c - current slopes per measured state and the least-squares position
 * estimate of docs/estimator.md §2, 3, 4.5.
 */
#include "fw_internal.h"

int16_t fw_slope_window(const fw_plan_t *plan, int16_t w, const fw_adc_t *adc, int32_t adc_half,
                        real_t lsb, fw_cplx_t *slope, real_t *t_mean_ticks, fw_cplx_t *i_mean)
{
    const fw_window_t *win = &plan->win[w];
    int16_t first = win->soc_first;
    int16_t n = win->soc_count;
    int16_t k;
    real_t t_sum = FW_REAL(0.0);
    real_t t_bar, stt = FW_REAL(0.0), sta = FW_REAL(0.0), stb = FW_REAL(0.0);
    real_t da_sum = FW_REAL(0.0), db_sum = FW_REAL(0.0);
    real_t sa, sb, ia, ib;
    int32_t a0, b0;

    if (!win->measured || n < 2 || first + n > adc->n_soc || first + n > FW_MAX_SOC) {
        return 0;
    }
    a0 = adc->ia[first];
    b0 = adc->ib[first];
    {
        /* at most FW_MAX_SOC (16) SOCs of 16 bits: every partial sum is a whole number below
         * 2^24, so the integer sum is the float sum */
        int32_t ticks = 0;
        for (k = 0; k < n; k++) {
            ticks += (int32_t)plan->soc[first + k];
        }
        t_sum = (real_t)ticks;
    }
    t_bar = t_sum / (real_t)n;
    /* Least squares on code differences: integer subtraction first, so a 24-bit converter
     * loses nothing to the float mantissa. */
    for (k = 0; k < n; k++) {
        real_t dt = (real_t)plan->soc[first + k] - t_bar;
        real_t da = (real_t)(adc->ia[first + k] - a0);
        real_t db = (real_t)(adc->ib[first + k] - b0);
        stt += dt * dt;
        sta += dt * da;
        stb += dt * db;
        da_sum += da;
        db_sum += db;
    }
    if (!(stt > FW_REAL(0.0))) {
        return 0;
    }
    sa = sta / stt * lsb * FW_TBCLK_HZ; /* A/s */
    sb = stb / stt * lsb * FW_TBCLK_HZ;
    ia = ((real_t)(a0 - adc_half) + da_sum / (real_t)n) * lsb;
    ib = ((real_t)(b0 - adc_half) + db_sum / (real_t)n) * lsb;
    /* two sensors, isolated neutral: alpha = a, beta = (a + 2b)/sqrt3 (docs/estimator.md §2) */
    *slope = fw_c(sa, (sa + FW_REAL(2.0) * sb) * FW_M_INV_SQRT3);
    *i_mean = fw_c(ia, (ia + FW_REAL(2.0) * ib) * FW_M_INV_SQRT3);
    *t_mean_ticks = t_bar;
    return 1;
}

fw_cplx_t fw_slope_diff(fw_cplx_t s_active, real_t t_active, fw_cplx_t s_zero, real_t t_zero,
                        real_t omega)
{
    /* Section 4.5: the zero-state slope is Gamma(theta)*(-rs*i - e - ...) = R(theta)*const in
     * steady state, so it rotates with the rotor; bring it to the active window's time. */
    fw_cplx_t rot = fw_cexpj(omega * (t_active - t_zero));
    return fw_csub(s_active, fw_cmul(s_zero, rot));
}

void fw_slope_solve(int16_t n_active, const int16_t vec[2], const fw_cplx_t di[2],
                  const real_t t[2], real_t kv, real_t omega, real_t gamma0_prior,
                  fw_est_out_t *out)
{
    fw_cplx_t y[2], u[2];
    int16_t k;

    out->n_active = 0;
    out->ok = 0;
    out->residual = FW_REAL(0.0);
    if (n_active < 1 || n_active > 2 || !(kv > FW_REAL(0.0))) {
        return;
    }
    /* y_k = Di_k * exp(+j phi_k) / kv = Gamma0 * u_k + g,  u_k = exp(j 2 phi_k)  (section 3) */
    for (k = 0; k < n_active; k++) {
        y[k] = fw_cscale(fw_cmul(di[k], fw_svpwm_vec_unit(vec[k])), FW_REAL(1.0) / kv);
        u[k] = fw_svpwm_vec_unit2(vec[k]);
    }
    if (n_active == 2) {
        /* g rotates at 2*omega between the two windows: with r_k = exp(j 2 omega (t_k - t_ref))
         * the model y_k = Gamma0 u_k + g r_k becomes w_k = Gamma0 v_k + g with w = y conj(r),
         * v = u conj(r): the same closed form, now exact for a rotating rotor. */
        real_t t_ref = FW_REAL(0.5) * (t[0] + t[1]);
        fw_cplx_t w[2], v[2], d, dw;
        real_t d2;
        real_t arg0 = FW_REAL(2.0) * omega * (t[0] - t_ref);
        real_t arg1 = FW_REAL(2.0) * omega * (t[1] - t_ref);
        fw_cplx_t rc0 = fw_cconj(fw_cexpj(arg0));
        /* the windows lie symmetric about t_ref whenever t0 + t1 is exact: then the second
         * rotation is the conjugate of the first, bit for bit (fw_sincos is odd in x for
         * 0 < |x| < pi/4, where it reduces nothing) */
        fw_cplx_t rc1 = (arg1 == -arg0 && arg0 != FW_REAL(0.0) && fw_fabs(arg0) < FW_REAL(0.78))
                            ? fw_cconj(rc0)
                            : fw_cconj(fw_cexpj(arg1));
        w[0] = fw_cmul(y[0], rc0);
        v[0] = fw_cmul(u[0], rc0);
        w[1] = fw_cmul(y[1], rc1);
        v[1] = fw_cmul(u[1], rc1);
        d = fw_csub(v[0], v[1]);
        dw = fw_csub(w[0], w[1]);
        d2 = fw_cabs2(d);
        if (!(d2 > FW_REAL(1e-6))) {
            return;
        }
        {
            fw_cplx_t p = fw_cmul(dw, fw_cconj(d));
            out->gamma0 = p.re / d2;
            out->residual = p.im / fw_sqrt(d2); /* the 4th equation, 1/H */
            out->g = fw_csub(fw_cscale(fw_cadd(w[0], w[1]), FW_REAL(0.5)),
                             fw_cscale(fw_cadd(v[0], v[1]), FW_REAL(0.5) * out->gamma0));
        }
        out->t_ref = t_ref;
        out->n_active = 2;
    } else {
        /* single-vector fallback: g = y - Gamma0_bar * u */
        out->gamma0 = gamma0_prior;
        out->g = fw_csub(y[0], fw_cscale(u[0], gamma0_prior));
        out->t_ref = t[0];
        out->n_active = 1;
    }
    out->gamma1 = fw_cabs(out->g);
    out->theta_raw = FW_REAL(0.5) * fw_atan2(out->g.im, out->g.re);
    out->ok = (int16_t)(out->gamma0 > FW_REAL(0.0) && out->gamma1 > FW_REAL(0.0) &&
                        out->gamma1 < out->gamma0);
}
