/* Guest instruction counter for qemu-user's TCG plugin interface (API version 1, qemu 7.2), for
 * the instruction counts in docs/benchmarks.md "aarch64". Debian's qemu-user supports -plugin but
 * ships neither plugins nor <qemu-plugin.h>, so the handful of entry points used here are declared
 * by hand (qemu resolves them from its own binary when it loads the plugin).
 *   gcc -O2 -shared -fPIC -o libinsncount.so cross/insncount.c
 *   qemu-aarch64 -L /usr/aarch64-linux-gnu -plugin ./libinsncount.so -d plugin BIN ARGS
 * Each translated block adds its instruction count to one 64-bit counter inline when it runs: no
 * helper call per block, so the count costs little time. The add is not atomic: count
 * single-threaded runs only (several guest threads would race on the counter). */
#include <inttypes.h>
#include <stddef.h>
#include <stdio.h>

typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 };

void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t,
                                           void (*)(qemu_plugin_id_t, struct qemu_plugin_tb *));
void qemu_plugin_register_vcpu_tb_exec_inline(struct qemu_plugin_tb *, enum qemu_plugin_op,
                                              void *, uint64_t);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t, void (*)(qemu_plugin_id_t, void *), void *);
void qemu_plugin_outs(const char *);

/* qemu refuses a plugin that does not state the API version it was written for. */
__attribute__((visibility("default"))) int qemu_plugin_version = 1;

static uint64_t insns;

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    (void)id;
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &insns,
                                             qemu_plugin_tb_n_insns(tb));
}

static void on_exit(qemu_plugin_id_t id, void *data) {
    (void)id;
    (void)data;
    char line[64];
    snprintf(line, sizeof line, "insns: %" PRIu64 "\n", insns);
    qemu_plugin_outs(line);
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id,
                                                               const void *info, int argc,
                                                               char **argv) {
    (void)info;
    (void)argc;
    (void)argv;
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    qemu_plugin_register_atexit_cb(id, on_exit, NULL);
    return 0;
}
