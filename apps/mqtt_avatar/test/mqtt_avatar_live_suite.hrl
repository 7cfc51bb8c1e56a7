%% The Common Test callbacks every live mqtt_avatar suite shares
%% (mqtt_avatar_SUITE, _families_, _light_, _state_SUITE): one EVATAR node
%% with a bridge listener and a real mosquitto per suite, a pairing per
%% case (mqtt_avatar_test_setup). Before including, define LIVE_LISTENER
%% (the listener's name, unique per suite), LIVE_CASE_PREFIX (text put
%% before a case's name to make its pairing and topic prefix) and
%% LIVE_FEEDBACK_MS (the pairing's feedback timeout).

-include_lib("common_test/include/ct.hrl").

-compile([export_all, nowarn_export_all]).

-import(mqtt_avatar_test_setup, [remember/2]).

-define(SETUP, mqtt_avatar_test_setup).

suite() -> [{timetrap, {seconds, 60}}].

init_per_suite(Config) ->
    ?SETUP:init_per_suite(?LIVE_LISTENER, Config).

end_per_suite(Config) ->
    ?SETUP:end_per_suite(?LIVE_LISTENER, Config).

init_per_testcase(Case, Config) ->
    ?SETUP:init_per_testcase(<<?LIVE_CASE_PREFIX, (atom_to_binary(Case))/binary>>,
                             ?LIVE_FEEDBACK_MS, Config).

end_per_testcase(_Case, Config) ->
    ?SETUP:end_per_testcase(Config).
