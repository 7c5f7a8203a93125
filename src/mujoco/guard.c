/* MuJoCo 2.2.2's mju_error must not return to its caller: the engine would go on with broken
 * state (and without a handler MuJoCo prints, waits for Enter and exits). mjsafe installs
 * mjsafe_error_handler, which jumps back to the mjsafe_guarded_* call that started the work
 * (setjmp/longjmp across MuJoCo's C frames only): that call returns 1, the message is kept per
 * thread, and the caller discards the mjData. Outside such a call, or with a Rust frame in between
 * (the control callback runs inside mj_step), the handler calls mjsafe_fatal_error instead,
 * which ends the process: a jump must never skip a Rust frame. */
#include <setjmp.h>
#include <stdio.h>

#include <mujoco/mujoco.h>

/* The innermost guarded call of this thread, and Rust frames entered since (callbacks). */
static _Thread_local jmp_buf* mjsafe_jump = NULL;
static _Thread_local int mjsafe_rust_depth = 0;
static _Thread_local char mjsafe_message[1024];

/* Rust (src/mujoco/mod.rs): prints the error, removes partial outputs, exits. */
extern void mjsafe_fatal_error(const char* message);

void mjsafe_error_handler(const char* message) {
  if (mjsafe_jump != NULL && mjsafe_rust_depth == 0) {
    snprintf(mjsafe_message, sizeof mjsafe_message, "%s", message);
    longjmp(*mjsafe_jump, 1);
  }
  mjsafe_fatal_error(message);
}

/* Called by the control callback on entry and exit: no jump while it runs. */
void mjsafe_enter_rust(void) { mjsafe_rust_depth++; }
void mjsafe_leave_rust(void) { mjsafe_rust_depth--; }

/* mj_step (forward = 0) or mj_forward (forward = 1) of d; 0 when done, 1 when MuJoCo raised an
 * error (its message from mjsafe_error_message): d is then unusable. */
int mjsafe_guarded(const mjModel* m, mjData* d, int forward) {
  jmp_buf here;
  jmp_buf* volatile outer = mjsafe_jump;
  volatile int depth = mjsafe_rust_depth;
  if (setjmp(here) != 0) {
    mjsafe_jump = outer;
    mjsafe_rust_depth = depth;
    return 1;
  }
  mjsafe_jump = &here;
  if (forward) {
    mj_forward(m, d);
  } else {
    mj_step(m, d);
  }
  mjsafe_jump = outer;
  return 0;
}

/* The message of this thread's last MuJoCo error caught by mjsafe_guarded (NUL-terminated). */
const char* mjsafe_error_message(void) { return mjsafe_message; }
