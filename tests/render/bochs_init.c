/* /init of the initramfs that tests/render/test_simd_primitives.py boots in Bochs: runs /check,
 * reports how it ended on the console, waits for the serial line to drain and powers off. */
#include <stdio.h>
#include <sys/reboot.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

int main(void) {
    pid_t child = fork();
    if (child == 0) {
        execl("/check", "check", (char*)0);
        perror("exec /check");
        _exit(127);
    }
    int status = 0;
    waitpid(child, &status, 0);
    if (WIFEXITED(status))
        printf("check exited with status %d\n", WEXITSTATUS(status));
    else
        printf("check killed by signal %d\n", WTERMSIG(status));
    fflush(stdout);
    tcdrain(1);
    sleep(3);
    sync();
    reboot(RB_POWER_OFF);
    return 0;
}
