%% @doc EUnit and PropEr tests of identity and of the per-pairing limits:
%% hashed credentials (evatar_auth), per-entity identities, ids reserved for
%% EVATAR, the Origin mark, the open-requests cap and the bound on a
%% Binding report (evatar_pairing_logic).
-module(evatar_identity_tests).

-include_lib("proper/include/proper.hrl").
-include_lib("eunit/include/eunit.hrl").

-define(P, <<"home">>).
-define(FP, <<"0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef">>).

%% ---------------------------------------------------------------------------
%% evatar_auth
%% ---------------------------------------------------------------------------

hash_verify_test() ->
    H = evatar_auth:hash(<<"s3cret">>, 1000),
    ?assertMatch({pbkdf2_sha256, 1000, <<_:16/binary>>, <<_:32/binary>>}, H),
    ?assertEqual(authenticated, evatar_auth:verify(#{credential => H}, <<"s3cret">>)),
    ?assertEqual(bad_credential, evatar_auth:verify(#{credential => H}, <<"s3creT">>)),
    ?assertEqual(bad_credential, evatar_auth:verify(#{credential => H}, <<>>)),
    ?assertEqual(bad_credential, evatar_auth:verify(refuse, <<"s3cret">>)),
    %% Two hashes of one credential differ: each has its own salt.
    ?assertNotEqual(H, evatar_auth:hash(<<"s3cret">>, 1000)).

%% The stored configuration holds no plain credential anywhere, and
%% normalising it again keeps it as it is (what a catalogue stores).
config_keeps_only_hashes_test() ->
    Opts = #{agent_credential => <<"agent-plain">>, avatar_credential => <<"avatar-plain">>,
             identities => [#{entity => <<"lamp">>, role => avatar,
                              credential => <<"lamp-plain">>}]},
    {ok, C} = evatar_pairing_logic:config(Opts),
    Bin = term_to_binary(C),
    [?assertEqual(nomatch, binary:match(Bin, Plain))
     || Plain <- [<<"agent-plain">>, <<"avatar-plain">>, <<"lamp-plain">>]],
    ?assertEqual({ok, C}, evatar_pairing_logic:config(C)).

config_refusals_test_() ->
    Bad = fun(Opts) -> evatar_pairing_logic:config(Opts) end,
    [?_assertMatch({error, {bad_option, {identities, duplicate_entity}}},
                   Bad(#{identities => [#{entity => <<"a">>, role => avatar, credential => <<"x">>},
                                        #{entity => <<"a">>, role => avatar, credential => <<"y">>}]})),
     ?_assertMatch({error, {bad_option, {identity, <<"a">>, no_credential_or_certificate}}},
                   Bad(#{identities => [#{entity => <<"a">>, role => avatar}]})),
     ?_assertMatch({error, {bad_option, {identity, <<"a">>, {cert_sha256, <<"zz">>}}}},
                   Bad(#{identities => [#{entity => <<"a">>, role => avatar,
                                          cert_sha256 => <<"zz">>}]})),
     ?_assertMatch({error, {bad_option, {unlisted_ids, open}}},
                   Bad(#{identities => [], unlisted_ids => open})),
     ?_assertMatch({error, {bad_option, {missing, [avatar_credential]}}},
                   Bad(#{agent_credential => <<"a">>})),
     ?_assertMatch({error, {bad_option, {agent_credential, {pbkdf2_sha256, 1, <<>>, <<>>}}}},
                   Bad(#{agent_credential => {pbkdf2_sha256, 1, <<>>, <<>>},
                         avatar_credential => <<"v">>}))].

identities_config() ->
    {ok, C} = evatar_pairing_logic:config(
                #{agent_credential => <<"ca">>, avatar_credential => <<"cv">>,
                  identities => [#{entity => <<"lamp">>, role => avatar, credential => <<"lamp-key">>},
                                 #{entity => <<"cam">>, role => avatar,
                                   cert_sha256 => string:uppercase(colons(?FP))},
                                 #{entity => <<"lock">>, role => avatar,
                                   credential => <<"lock-key">>, cert_sha256 => ?FP}]}),
    C.

%% A fingerprint is accepted as hex, with colons in either case, or as the
%% whole line openssl prints; all normalise to lower-case hex.
fingerprint_forms_test_() ->
    Norm = fun(F) ->
                   {ok, #{identities := [#{cert_sha256 := N}]}} =
                       evatar_pairing_logic:config(
                         #{identities => [#{entity => <<"cam">>, role => avatar,
                                            cert_sha256 => F}]}),
                   N
           end,
    Up = string:uppercase(colons(?FP)),
    [?_assertEqual(?FP, Norm(F))
     || F <- [?FP, colons(?FP), Up, <<"sha256 Fingerprint=", Up/binary>>,
              <<"SHA256 Fingerprint=", Up/binary, "\n">>]].

colons(Hex) ->
    iolist_to_binary(lists:join(<<":">>, [<<A, B>> || <<A, B>> <= Hex])).

verify(Role, Id, Auth, C) ->
    evatar_auth:verify(evatar_auth:requirement(Role, Id, C), Auth).

%% A listed EntityID joins with its own identity only; an unlisted one is
%% refused unless the pairing says unlisted_ids => role_credential.
identity_semantics_test() ->
    C = identities_config(),
    Cert = #{sha256 => ?FP, cn => <<"cam">>},
    ?assertEqual(authenticated, verify(avatar, <<"lamp">>, <<"lamp-key">>, C)),
    ?assertEqual(bad_credential, verify(avatar, <<"lamp">>, <<"cv">>, C)),
    ?assertEqual(bad_credential, verify(agent, <<"lamp">>, <<"lamp-key">>, C)),
    ?assertEqual(bad_credential, verify(avatar, <<"lamp">>, <<"lock-key">>, C)),
    ?assertEqual(bad_credential, verify(avatar, <<"other">>, <<"cv">>, C)),
    ?assertEqual(bad_credential, verify(agent, <<"va">>, <<"ca">>, C)),
    %% A certificate identity: the fingerprint, whatever credential.
    ?assertEqual(authenticated,
                 verify(avatar, <<"cam">>, #{credential => <<>>, peer_cert => Cert}, C)),
    ?assertEqual(bad_credential, verify(avatar, <<"cam">>, <<"cv">>, C)),
    ?assertEqual(bad_credential,
                 verify(avatar, <<"cam">>, #{credential => <<>>, peer_cert => undefined}, C)),
    ?assertEqual(bad_credential,
                 verify(avatar, <<"cam">>,
                        #{credential => <<>>,
                          peer_cert => #{sha256 => binary:copy(<<"0">>, 64)}}, C)),
    %% Both named: both needed.
    ?assertEqual(authenticated,
                 verify(avatar, <<"lock">>, #{credential => <<"lock-key">>, peer_cert => Cert}, C)),
    ?assertEqual(bad_credential, verify(avatar, <<"lock">>, <<"lock-key">>, C)),
    ?assertEqual(bad_credential,
                 verify(avatar, <<"lock">>, #{credential => <<"x">>, peer_cert => Cert}, C)),
    %% Unlisted ids with the role credential, when the pairing allows it.
    C2 = C#{unlisted_ids => role_credential},
    ?assertEqual(authenticated, verify(avatar, <<"other">>, <<"cv">>, C2)),
    ?assertEqual(authenticated, verify(agent, <<"va">>, <<"ca">>, C2)),
    ?assertEqual(bad_credential, verify(avatar, <<"lamp">>, <<"cv">>, C2)).

reserved_ids_test_() ->
    [?_assert(evatar_auth:reserved(Id))
     || Id <- [<<"EVATAR">>, <<"evatar">>, <<" Evatar ">>, <<"E.V.A.T.A.R">>, <<"evatar-">>,
               <<"EVATAR\t">>]] ++
    [?_assertNot(evatar_auth:reserved(Id))
     || Id <- [<<"evatar1">>, <<"va-1">>, <<"EVATARS">>, <<"my-evatar-lamp">>, <<>>]].

log_id_test() ->
    Long = binary:copy(<<"x">>, 60000),
    L = evatar_auth:log_id(Long),
    ?assert(byte_size(L) < 100),
    ?assertEqual(<<"short">>, evatar_auth:log_id(<<"short">>)).

%% ---------------------------------------------------------------------------
%% The pairing logic
%% ---------------------------------------------------------------------------

config(Extra) ->
    {ok, C} = evatar_pairing_logic:config(maps:merge(#{agent_credential => <<"ca">>,
                                                       avatar_credential => <<"cv">>,
                                                       feedback_timeout => 100}, Extra)),
    C.

h(Event, St) -> evatar_pairing_logic:handle(Event, 1000, St).

reply(Effects) -> [R || {reply, R} <- Effects].

ok(Event, St) ->
    {St1, Effects} = h(Event, St),
    ?assertEqual([ok], reply(Effects)),
    St1.

entry(Cat, Type) -> #{category => Cat, type => Type, parameters => []}.

desc(Id, Type, Components) ->
    #{entity_id => Id, api_name => <<"X">>, entity_type => Type, context => <<>>,
      components => Components}.

va() -> desc(<<"va">>, agent, [#{id => <<"Emu">>, services => [entry(<<"A">>, <<"Fb">>)],
                                  consumes => [entry(<<"A">>, <<"On">>)]}]).
av() -> desc(<<"av">>, avatar, [#{id => <<"Light">>, services => [entry(<<"A">>, <<"On">>)],
                                   consumes => [entry(<<"A">>, <<"Fb">>)]}]).

bound(Extra) ->
    St0 = evatar_pairing_logic:new(?P, config(Extra)),
    St1 = ok({join, agent, <<"va">>, authenticated}, St0),
    St2 = ok({join, avatar, <<"av">>, authenticated}, St1),
    ok({describe, <<"av">>, av()}, ok({describe, <<"va">>, va()}, St2)).

request(Id) ->
    #{id => Id, context => request, sender => <<"Emu">>, receiver => <<"Light">>,
      in_reply_to => undefined, timestamp => 1, seq => undefined, epoch => undefined,
      body => entry(<<"A">>, <<"On">>)}.

delivered(Effects) -> [S || {deliver, _, S} <- Effects].

join_refuses_bad_ids_test() ->
    St = evatar_pairing_logic:new(?P, config(#{})),
    {_, E1} = h({join, avatar, binary:copy(<<"x">>, 60000), <<"cv">>}, St),
    ?assertEqual([{error, id_too_long}], reply(E1)),
    %% Logged by the bridge connection, with the id cut (agent_bridge_conn).
    ?assert(byte_size(term_to_binary(E1)) < 1000),
    {_, E2} = h({join, avatar, <<"Evatar">>, <<"cv">>}, St),
    ?assertEqual([{error, reserved_id}], reply(E2)),
    {_, E3} = h({join, avatar, <<"av">>, bad_credential}, St),
    ?assertEqual([{error, bad_credential}], reply(E3)),
    {_, E4} = h({join, avatar, <<"av">>, <<"wrong">>}, St),
    ?assertEqual([{error, bad_credential}], reply(E4)).

%% A detached entity listed with its own credential cannot be taken over by
%% a holder of the role credential.
detached_listed_entity_kept_test() ->
    C = config(#{identities => [#{entity => <<"lamp">>, role => avatar,
                                  credential => <<"lamp-key">>}],
                 unlisted_ids => role_credential}),
    St0 = evatar_pairing_logic:new(?P, C),
    St1 = ok({join, avatar, <<"lamp">>, <<"lamp-key">>, <<"s1">>}, St0),
    {St2, _} = h({detach, <<"lamp">>}, St1),
    {St3, E} = h({join, avatar, <<"lamp">>, <<"cv">>, <<"s2">>}, St2),
    ?assertEqual([{error, bad_credential}], reply(E)),
    ?assertEqual([<<"lamp">>], evatar_pairing_logic:entity_ids(St3)),
    %% Its owner comes back (never described, it starts afresh: Resumed false).
    {_, E2} = h({resume, avatar, <<"lamp">>, <<"lamp-key">>, <<"s1">>, 0, 1}, St3),
    ?assertEqual([{ok, false, <<>>}], reply(E2)).

describe_refuses_bad_components_test() ->
    St0 = evatar_pairing_logic:new(?P, config(#{max_consumes => 2})),
    St = ok({join, avatar, <<"av">>, authenticated}, St0),
    Comp = fun(Id, Consumes) -> #{id => Id, services => [], consumes => Consumes} end,
    Refused = fun(D) ->
                      {St1, E} = h({describe, <<"av">>, D}, St),
                      ?assertEqual(St, St1),
                      [{error, Msg}] = reply(E),
                      Msg
              end,
    M1 = Refused(desc(<<"av">>, avatar, [Comp(<<"EVATAR">>, [])])),
    ?assertNotEqual(nomatch, binary:match(M1, <<"reserved">>)),
    M2 = Refused(desc(<<"av">>, avatar, [Comp(binary:copy(<<"c">>, 129), [])])),
    ?assertNotEqual(nomatch, binary:match(M2, <<"max_id_length">>)),
    M3 = Refused(desc(<<"av">>, avatar, [Comp(<<"c">>, [entry(binary:copy(<<"&">>, 30), <<"T">>)])])),
    ?assertNotEqual(nomatch, binary:match(M3, <<"ServiceCategory">>)),
    M4 = Refused(desc(<<"av">>, avatar, [Comp(<<"c">>, [entry(<<"A">>, <<"T">>) || _ <- [1, 2, 3]])])),
    ?assertNotEqual(nomatch, binary:match(M4, <<"max_consumes">>)),
    ok({describe, <<"av">>, desc(<<"av">>, avatar, [Comp(<<"c">>, [entry(<<"A">>, <<"T">>)])])}, St).

open_requests_cap_test() ->
    St = bound(#{max_open_requests => 3}),
    {St1, E1} = lists:foldl(fun(N, {S, _}) -> h({signal, <<"va">>, request(integer_to_binary(N))}, S)
                            end, {St, []}, [1, 2, 3]),
    [#{context := request}] = delivered(E1),
    {St2, E2} = h({signal, <<"va">>, request(<<"4">>)}, St1),
    [#{context := error, origin := evatar, in_reply_to := <<"4">>,
       body := #{type := <<"TooManyRequests">>}}] = delivered(E2),
    ?assertEqual(3, maps:get(pending, evatar_pairing_logic:stats(St2))),
    %% Feedback closes one: one more may open.
    Fb = (request(<<"f1">>))#{context := feedback, sender := <<"Light">>, receiver := <<"Emu">>,
                             in_reply_to := <<"1">>},
    St3 = element(1, h({signal, <<"av">>, Fb}, St2)),
    {_, E4} = h({signal, <<"va">>, request(<<"5">>)}, St3),
    [#{context := request}] = delivered(E4),
    %% A timeout closes one too.
    {St5, E5} = h({timeout, {feedback, <<"Emu">>, <<"2">>}}, St3),
    %% The requester gets Timeout, the provider RequestClosed (protocol.md 4.3).
    [#{context := feedback, sender := <<"EVATAR">>, origin := evatar, receiver := <<"Emu">>,
       body := #{type := <<"Timeout">>}},
     #{context := event, origin := evatar, receiver := <<"Light">>,
       body := #{type := <<"RequestClosed">>}}] = delivered(E5),
    {_, E6} = h({signal, <<"va">>, request(<<"6">>)}, St5),
    [#{context := request}] = delivered(E6).

origin_and_signal_id_test() ->
    St = bound(#{}),
    {_, E1} = h({signal, <<"va">>, (request(<<"1">>))#{origin => evatar}}, St),
    [#{context := error, body := #{type := <<"BadSignal">>}}] = delivered(E1),
    {_, E2} = h({signal, <<"va">>, request(binary:copy(<<"i">>, 60000))}, St),
    [#{context := error, in_reply_to := undefined, body := #{type := <<"IdTooLong">>}}]
        = delivered(E2),
    {_, E3} = h({signal, <<"va">>, request(<<"ok">>)}, St),
    [#{context := request} = Routed] = delivered(E3),
    ?assertNot(maps:is_key(origin, Routed)).

%% The constants the bound is computed with are the encoder's.
report_constants_test() ->
    Size = fun(R) -> iolist_size(bil_control:encode({binding, R})) end,
    Empty = #{entities => [], bound => [], unbound => []},
    ?assertEqual(77, Size(Empty)),
    ?assertEqual(21, Size(Empty#{entities => [<<>>]}) - Size(Empty)),
    Max = 99999999999999999999,
    Row = #{consumer => #{entity => <<>>, component => <<>>},
            provider => #{entity => <<>>, component => <<>>},
            category => <<>>, type => <<>>, score => Max, candidates => Max},
    ?assertEqual(301, Size(Empty#{bound => [Row]}) - Size(Empty)),
    Unbound = #{consumer => #{entity => <<>>, component => <<>>}, category => <<>>,
                type => <<>>, reason => parameters_mismatch},
    ?assert(Size(Empty#{unbound => [Unbound]}) - Size(Empty) < 301).

%% However entities describe themselves (long ids, characters that grow
%% when escaped, many Consumes), every Binding report the pairing sends
%% stays within max_binding_report.
binding_report_bound_test_() ->
    {timeout, 300,
     ?_test(ok = evatar_test_proper:check(prop_report_bound(), 100))}.

prop_report_bound() ->
    ?FORALL(Entities, resize(12, non_empty(list(entity_gen()))),
            begin
                Limit = 8192,
                St0 = evatar_pairing_logic:new(
                        ?P, config(#{max_binding_report => Limit, max_id_length => 24,
                                     max_avatars => 100, max_consumes => 8})),
                {_, Sizes} =
                    lists:foldl(
                      fun({N, {Role, Id, Comps}}, {St, Acc}) ->
                              Eid = <<(integer_to_binary(N))/binary, Id/binary>>,
                              case h({join, Role, Eid, authenticated}, St) of
                                  {St1, [{reply, ok} | _]} ->
                                      {St2, E} = h({describe, Eid, desc(Eid, Role, Comps)}, St1),
                                      {St2, Acc ++ [iolist_size(bil_control:encode({binding, R}))
                                                    || {report, _, R} <- E]};
                                  {St1, _} ->
                                      {St1, Acc}
                              end
                      end, {St0, []}, lists:zip(lists:seq(1, length(Entities)), Entities)),
                lists:all(fun(S) -> S =< Limit end, Sizes)
            end).

entity_gen() ->
    {oneof([agent, avatar]), text(10), resize(4, list(component_gen()))}.

component_gen() ->
    ?LET({Id, Services, Consumes}, {text(24), resize(3, list(entry_gen())),
                                    resize(6, list(entry_gen()))},
         #{id => <<"c", Id/binary>>, services => Services, consumes => Consumes}).

entry_gen() ->
    ?LET({Cat, Type}, {oneof([<<"A">>, <<"B">>]), oneof([<<"On">>, text(24)])},
         entry(Cat, Type)).

text(Max) ->
    ?LET(N, range(1, Max), ?LET(Cs, vector(N, oneof([$a, $&, $<, $z, $1])), list_to_binary(Cs))).
